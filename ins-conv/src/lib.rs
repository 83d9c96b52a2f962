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
pub mod op;
pub mod reference;
pub mod vnni_im2col;

pub use engine::Engine;
pub use geometry::ConvGeometry;
pub use op::{conv2d, kernel_device};

/// The arithmetic of a network's convolutions, as a user picks it (`--precision`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// f32 throughout.
    #[default]
    F32,
    /// BF16 inputs and f32 sums, on AMX or with AVX-512 BF16 where the CPU has either; f32
    /// elsewhere.
    Bf16,
}

impl Precision {
    /// What actually runs on this CPU: `Bf16` only where a BF16 engine is available.
    pub fn effective(self) -> Precision {
        match self {
            Precision::Bf16 if Engine::bf16().is_some() => Precision::Bf16,
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
            _ => Err(format!("unknown precision {s:?} (known: f32, bf16)")),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
        })
    }
}
