//! Forward-mode differentiation through the SDF networks' layers: each value carries the three
//! tangents ∂/∂x, ∂/∂y, ∂/∂z, so ∇f comes out of the same tensor ops as f.

use burn::nn::Linear;
use burn::prelude::*;

use super::BETA;
use crate::kernels::dense::dense;
use crate::kernels::dense_blocks::trained_product;
use crate::kernels::softplus::{softplus, softplus_slope};
use crate::modules::encoding::{FourierEncoding, angles, octave_pairs};

/// Value and forward-mode tangents of a layer stack: `h [N, D]`, `t [3N, D]` (the three
/// tangents stacked along rows, tangent k in rows `kN..(k+1)N`).
pub(super) struct Dual {
    pub(super) h: Tensor<2>,
    pub(super) t: Tensor<2>,
}

impl Dual {
    pub(super) fn linear(self, l: &Linear) -> Self {
        let w = l.weight.val();
        Self {
            h: dense(l, self.h),
            t: trained_product(self.t, w),
        }
    }

    /// The output layer `[.., 1 + F]`: values of all columns, tangents of the distance's
    /// alone (the gradient is all [`Dual::split`] reads; the features' tangents were a matmul
    /// and its backward for nothing).
    pub(super) fn output(self, l: &Linear) -> Self {
        let w = l.weight.val();
        let [d_in, _] = w.dims();
        Self {
            h: dense(l, self.h),
            t: trained_product(self.t, w.slice([0..d_in, 0..1])),
        }
    }

    pub(super) fn softplus(self) -> Self {
        let [n, d] = self.h.dims();
        let slope = softplus_slope(self.h.clone(), BETA);
        let slope = slope
            .unsqueeze_dim::<3>(0)
            .expand([3, n, d])
            .reshape([3 * n, d]);
        Self {
            h: softplus(self.h, BETA),
            t: self.t * slope,
        }
    }

    pub(super) fn cat(self, other: Dual, scale: f32) -> Self {
        Self {
            h: Tensor::cat(vec![self.h, other.h], 1).mul_scalar(scale),
            t: Tensor::cat(vec![self.t, other.t], 1).mul_scalar(scale),
        }
    }

    /// Splits the output into (sdf [N], features [N, F], ∇sdf [N, 3]).
    pub(super) fn split(self) -> (Tensor<1>, Tensor<2>, Tensor<2>) {
        let [n, d] = self.h.dims();
        let sdf = self.h.clone().slice([0..n, 0..1]).reshape([n]);
        let features = self.h.slice([0..n, 1..d]);
        let grad = self.t.slice([0..3 * n, 0..1]).reshape([3, n]).transpose();
        (sdf, features, grad)
    }
}

/// The positional encoding and its derivatives with respect to each coordinate, as a [`Dual`].
pub(super) fn encode_dual(x: Tensor<2>, n_freqs: usize) -> Dual {
    let [n, _] = x.dims();
    let device = x.device();
    let enc = FourierEncoding::new(n_freqs);
    let d = enc.d_out(3);
    // d/dx of [x, sin(2^j x), cos(2^j x)] elementwise: [1, 2^j cos(2^j x), −2^j sin(2^j x)].
    let ones = Tensor::<2>::ones([n, 3], &device);
    let deriv = if n_freqs == 0 {
        ones
    } else {
        let scales = enc.octaves(&device);
        let angles = angles(x.clone(), scales.clone());
        let waves = octave_pairs(
            angles.clone().cos() * scales.clone(),
            angles.sin() * scales.neg(),
        );
        Tensor::cat(vec![ones, waves], 1)
    };
    // Column c of the encoding belongs to coordinate c mod 3.
    let masks: Vec<f32> = (0..3)
        .flat_map(|k| (0..d).map(move |c| if c % 3 == k { 1.0 } else { 0.0 }))
        .collect();
    let masks = Tensor::<1>::from_floats(masks.as_slice(), &device).reshape([3, 1, d]);
    let t = (deriv.unsqueeze_dim::<3>(0).expand([3, n, d]) * masks).reshape([3 * n, d]);
    Dual {
        h: enc.encode(x),
        t,
    }
}
