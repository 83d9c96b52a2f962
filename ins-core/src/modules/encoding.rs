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
    ///
    /// Every octave at once (`x·2^k` broadcast over `k`), so a GPU step builds it with a few
    /// kernels: a piece per octave and function joined by `cat` took one copy kernel a piece
    /// (21 for a position at NeRF's 10 octaves).
    pub fn encode(&self, x: Tensor<2>) -> Tensor<2> {
        if self.n_freqs == 0 {
            return x;
        }
        let angles = angles(x.clone(), self.octaves(&x.device()));
        Tensor::cat(vec![x, octave_pairs(angles.clone().sin(), angles.cos())], 1)
    }

    /// `2^k` for every octave k, `[1, n, 1]`.
    pub fn octaves(&self, device: &Device) -> Tensor<3> {
        let scales: Vec<f32> = (0..self.n_freqs).map(|k| (1u64 << k) as f32).collect();
        Tensor::<1>::from_floats(scales.as_slice(), device).reshape([1, self.n_freqs, 1])
    }
}

/// `x·2^k` for every octave k, given the [`FourierEncoding::octaves`]: `[N, d] → [N, n, d]`
/// (exact: a power of two).
pub fn angles(x: Tensor<2>, octaves: Tensor<3>) -> Tensor<3> {
    let [n, d] = x.dims();
    x.reshape([n, 1, d]) * octaves
}

/// Two `[N, n, d]` tensors as `[N, n·2·d]`: for each octave, `a`'s `d` columns then `b`'s.
pub fn octave_pairs(a: Tensor<3>, b: Tensor<3>) -> Tensor<2> {
    let [n, octaves, d] = a.dims();
    Tensor::stack::<4>(vec![a, b], 2).reshape([n, octaves * 2 * d])
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

    #[test]
    fn no_octaves_is_the_input_and_the_gradient_is_the_derivative() {
        let d = Device::flex().autodiff();
        let x = Tensor::<2>::from_floats([[0.3, -1.2]], &d);
        assert_eq!(
            FourierEncoding::new(0).encode(x.clone()).into_data(),
            x.clone().into_data()
        );
        // d/dx of Σ encode(x) = 1 + Σ_k 2^k (cos(2^k x) − sin(2^k x)).
        let x = x.require_grad();
        let g = FourierEncoding::new(3).encode(x.clone()).sum().backward();
        let got = x.grad(&g).unwrap().into_data().try_to_vec::<f32>().unwrap();
        for (i, v) in [0.3f32, -1.2].iter().enumerate() {
            let want: f32 = 1.0
                + (0..3)
                    .map(|k| {
                        let f = (1 << k) as f32;
                        f * ((f * v).cos() - (f * v).sin())
                    })
                    .sum::<f32>();
            assert!(
                (got[i] - want).abs() < 1e-5,
                "{got:?}: {i} should be {want}"
            );
        }
    }
}
