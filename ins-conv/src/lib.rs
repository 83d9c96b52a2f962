//! 2D convolution for the CPU as a Burn op with its own backward: im2col over chunks of pixels
//! and one GEMM per chunk, in f32 or with BF16 inputs and f32 sums, on Intel AMX's tile
//! registers or by AVX-512 BF16 dot products, whichever the CPU has.
//!
//! VGG-16 runs every stylization step of every variant; this op is its convolution when
//! `--precision bf16` is asked for (see `vgg-import`).

pub mod amx;
pub mod bf16;
pub mod conv;
pub mod dpbf16;
pub mod engine;
pub mod geometry;
pub mod im2col;
pub mod kernel_cache;
pub mod kernel_matrix;
pub mod max_pool;
pub mod op;
pub mod reference;
pub mod vnni_im2col;

pub use engine::Engine;
pub use geometry::ConvGeometry;
pub use max_pool::max_pool_2x2;
pub use op::{conv2d, half_device, kernel_device};

/// The arithmetic of a network's convolutions, as a user picks it (`--precision`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// f32 throughout.
    #[default]
    F32,
    /// BF16 inputs and f32 sums, on AMX or with AVX-512 BF16 where the CPU has either; f32
    /// elsewhere.
    Bf16,
    /// f16 activations and weights in Burn's own convolution, on a GPU whose adapter runs f16
    /// shaders (wgpu); f32 elsewhere. Half the memory traffic of f32 on a GPU; on a CPU the
    /// BF16 engine is the reduced precision that pays.
    F16,
}

impl Precision {
    /// What actually runs on this CPU: `Bf16` only where a BF16 engine is available.
    pub fn effective(self) -> Precision {
        match self {
            Precision::Bf16 if Engine::bf16().is_some() => Precision::Bf16,
            _ => Precision::F32,
        }
    }

    /// What actually runs on `device`: `Bf16` on flex where this CPU has a BF16 engine, `F16`
    /// on a GPU device that supports f16, `F32` otherwise.
    pub fn effective_on(self, device: &burn::prelude::Device) -> Precision {
        match self {
            Precision::Bf16 if kernel_device(device) => self.effective(),
            Precision::F16 if half_device(device) => Precision::F16,
            _ => Precision::F32,
        }
    }
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f32" => Ok(Precision::F32),
            "bf16" => Ok(Precision::Bf16),
            "f16" => Ok(Precision::F16),
            _ => Err(format!("unknown precision {s:?} (known: f32, bf16, f16)")),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
            Precision::F16 => "f16",
        })
    }
}
