//! Fourier (NeRF positional) encoding: `x ↦ [x, sin(2^k x), cos(2^k x)]` for k < n.

use burn::prelude::*;

/// Encodes coordinates with `n_freqs` octaves of sines and cosines, keeping the input itself.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct FourierEncoding {
    /// Number of octaves (NeRF: 10 for position, 4 for direction).
    pub n_freqs: usize,
}

impl FourierEncoding {
    /// Encoding with `n_freqs` octaves.
    pub fn new(n_freqs: usize) -> Self {
        Self { n_freqs }
    }

    /// Width of the encoding of a `d_in`-dimensional input.
    pub fn d_out(&self, d_in: usize) -> usize {
        d_in * (1 + 2 * self.n_freqs)
    }

    /// `[N, d] → [N, d·(1+2n)]`, ordered as NeRF does: x, then (sin, cos) per octave.
    pub fn encode(&self, x: Tensor<2>) -> Tensor<2> {
        let mut parts = Vec::with_capacity(1 + 2 * self.n_freqs);
        parts.push(x.clone());
        for k in 0..self.n_freqs {
            let scaled = x.clone().mul_scalar((1u64 << k) as f32);
            parts.push(scaled.clone().sin());
            parts.push(scaled.cos());
        }
        Tensor::cat(parts, 1)
    }
}
