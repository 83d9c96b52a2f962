//! A convolution's kernel as the left operand of its GEMM: as it is for the forward, flipped
//! with its channels swapped for the input gradient, in f32 or packed to BF16 tiles.

use rayon::prelude::*;

use crate::bf16::PackedLeft;
use crate::engine::Engine;
use crate::geometry::ConvGeometry;

/// A convolution's kernel as the left operand of its GEMM, in the layout its engine reads.
/// Building it costs a pass over the weights (a BF16 packing, a flip for the input gradient);
/// a frozen network's can be built once and kept (see [`crate::kernel_cache`]).
pub enum KernelMatrix {
    /// Row-major f32 `[m, k]` (gemm).
    F32(Vec<f32>),
    /// BF16 tiles, for a BF16 engine.
    Bf16(PackedLeft, Engine),
}

/// A kernel matrix, borrowed: the f32 forward reads the weights as they are.
#[derive(Clone, Copy)]
pub(crate) enum Left<'a> {
    F32(&'a [f32]),
    Bf16(&'a PackedLeft, Engine),
}

impl KernelMatrix {
    /// The forward's left operand: `w` as `[c_out, c_in · kh · kw]`.
    pub fn forward(w: &[f32], g: &ConvGeometry, engine: Engine) -> Self {
        match engine {
            Engine::F32 => KernelMatrix::F32(w.to_vec()),
            bf16 => KernelMatrix::Bf16(PackedLeft::new(w, g.c_out, g.taps()), bf16),
        }
    }

    /// The input gradient's left operand: the flipped kernel with its channels swapped,
    /// `[c_in, c_out · kh · kw]`.
    pub fn input_grad(w: &[f32], g: &ConvGeometry, engine: Engine) -> Self {
        let flipped = flipped_kernel(w, g);
        match engine {
            Engine::F32 => KernelMatrix::F32(flipped),
            bf16 => {
                let k = g.c_out * g.kernel[0] * g.kernel[1];
                KernelMatrix::Bf16(PackedLeft::new(&flipped, g.c_in, k), bf16)
            }
        }
    }

    pub(crate) fn left(&self) -> Left<'_> {
        match self {
            KernelMatrix::F32(v) => Left::F32(v),
            KernelMatrix::Bf16(p, engine) => Left::Bf16(p, *engine),
        }
    }
}

/// The flipped kernel with its channels swapped, `[c_in, c_out · kh · kw]`: the input gradient
/// is the convolution of the output gradient with it.
fn flipped_kernel(w: &[f32], g: &ConvGeometry) -> Vec<f32> {
    let taps = g.kernel[0] * g.kernel[1];
    let mut left = vec![0.0f32; g.c_in * g.c_out * taps];
    left.par_chunks_mut(g.c_out * taps)
        .enumerate()
        .for_each(|(ci, row)| {
            for (co, dst) in row.chunks_mut(taps).enumerate() {
                let src = &w[(co * g.c_in + ci) * taps..][..taps];
                // Flipping both axes of a row-major kernel reverses it.
                dst.iter_mut()
                    .zip(src.iter().rev())
                    .for_each(|(d, &v)| *d = v);
            }
        });
    left
}
