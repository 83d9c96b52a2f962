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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_is_x_then_sin_cos_per_octave() {
        let d = Device::flex();
        let x = Tensor::<2>::from_floats([[0.3, -1.2]], &d);
        let e = FourierEncoding::new(3);
        assert_eq!(e.d_out(2), 14);
        let v = e.encode(x).into_data().try_to_vec::<f32>().unwrap();
        let mut want = vec![0.3f32, -1.2];
        for k in 0..3 {
            let f = (1 << k) as f32;
            want.extend([
                (0.3 * f).sin(),
                (-1.2 * f).sin(),
                (0.3 * f).cos(),
                (-1.2 * f).cos(),
            ]);
        }
        for (a, b) in v.iter().zip(&want) {
            assert!((a - b).abs() < 1e-6, "{v:?} vs {want:?}");
        }
    }
}
