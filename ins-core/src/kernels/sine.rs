//! `sin(ω·z)` as one op on Flex with its own backward (`ω·cos(ω·z)·g`), through a vectorized
//! polynomial. Flex computes `sin` and `cos` element by element with libm calls: a fifth of a
//! SIREN step went there. Other backends use ordinary tensor ops ([`scaled_sin`] picks).

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, DispatchDevice, Flex, TensorData,
    TensorMetadata, backend_extension,
};
use burn::prelude::*;

use crate::kernels::flex::filled;

/// The kernels: range reduction to `[-π, π]` (two-constant, exact for `|x|` below ~10⁵),
/// then Taylor polynomials to degree 15 (sin) and 16 (cos): absolute error below 2·10⁻⁶.
pub mod kernel {
    const INV_TWO_PI: f32 = 0.159_154_94;
    /// 2π split so that `k·TWO_PI_HI` is exact for integer `k` up to 2¹⁵.
    const TWO_PI_HI: f32 = 6.281_25;
    const TWO_PI_LO: f32 = 0.001_935_307_2;
    /// Adding and subtracting 1.5·2²³ rounds to the nearest integer, in any SIMD width.
    const ROUND: f32 = 12_582_912.0;

    #[inline(always)]
    fn reduce(x: f32) -> f32 {
        let k = (x * INV_TWO_PI + ROUND) - ROUND;
        (x - k * TWO_PI_HI) - k * TWO_PI_LO
    }

    /// `sin(x)`.
    #[inline(always)]
    pub fn sin(x: f32) -> f32 {
        let r = reduce(x);
        let r2 = r * r;
        let p = -1.0 / 1_307_674_368_000.0;
        let p = p * r2 + 1.0 / 6_227_020_800.0;
        let p = p * r2 - 1.0 / 39_916_800.0;
        let p = p * r2 + 1.0 / 362_880.0;
        let p = p * r2 - 1.0 / 5_040.0;
        let p = p * r2 + 1.0 / 120.0;
        let p = p * r2 - 1.0 / 6.0;
        r + r * r2 * p
    }

    /// `cos(x)`.
    #[inline(always)]
    pub fn cos(x: f32) -> f32 {
        let r = reduce(x);
        let r2 = r * r;
        let p = 1.0 / 20_922_789_888_000.0;
        let p = p * r2 - 1.0 / 87_178_291_200.0;
        let p = p * r2 + 1.0 / 479_001_600.0;
        let p = p * r2 - 1.0 / 3_628_800.0;
        let p = p * r2 + 1.0 / 40_320.0;
        let p = p * r2 - 1.0 / 720.0;
        let p = p * r2 + 1.0 / 24.0;
        let p = p * r2 - 0.5;
        1.0 + r2 * p
    }

    use std::mem::MaybeUninit;

    #[inline(always)]
    fn forward_loop(z: &[f32], omega: f32, out: &mut [MaybeUninit<f32>]) {
        for (o, &z) in out.iter_mut().zip(z) {
            o.write(sin(omega * z));
        }
    }

    #[inline(always)]
    fn backward_loop(z: &[f32], g: &[f32], omega: f32, out: &mut [MaybeUninit<f32>]) {
        for ((o, &z), &g) in out.iter_mut().zip(z).zip(g) {
            o.write(omega * cos(omega * z) * g);
        }
    }

    crate::kernels::flex::vectorized! {
        /// `out = sin(ω·z)`.
        pub fn forward(
            z: &[f32],
            omega: f32,
            out: &mut [MaybeUninit<f32>],
        ) = forward_loop;
    }

    crate::kernels::flex::vectorized! {
        /// `out = ω·cos(ω·z)·g`.
        pub fn backward(
            z: &[f32],
            g: &[f32],
            omega: f32,
            out: &mut [MaybeUninit<f32>],
        ) = backward_loop;
    }
}

/// The op and its gradient as backend operations.
#[backend_extension(Flex, Autodiff)]
pub trait ScaledSineOps: Backend {
    /// `sin(ω·z)`, any shape.
    fn scaled_sin(z: FloatTensor<Self>, omega: f32) -> FloatTensor<Self>;
    /// `ω·cos(ω·z)·grad`.
    fn scaled_sin_backward(
        z: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        omega: f32,
    ) -> FloatTensor<Self>;
}

fn contiguous(t: &FlexTensor) -> FlexTensor {
    assert_eq!(t.dtype(), DType::F32, "the sine op runs in f32");
    t.to_contiguous()
}

impl ScaledSineOps for Flex {
    fn scaled_sin(z: FlexTensor, omega: f32) -> FlexTensor {
        let shape = z.shape();
        let z = contiguous(&z);
        let z = z.as_slice::<f32>().expect("contiguous f32");
        let out = filled(z.len(), |at, o| {
            kernel::forward(&z[at..][..o.len()], omega, o)
        });
        FlexTensor::from_data(TensorData::new(out, shape))
    }

    fn scaled_sin_backward(z: FlexTensor, grad: FlexTensor, omega: f32) -> FlexTensor {
        let shape = z.shape();
        let (z, g) = (contiguous(&z), contiguous(&grad));
        let z = z.as_slice::<f32>().expect("contiguous f32");
        let g = g.as_slice::<f32>().expect("contiguous f32");
        let out = filled(z.len(), |at, o| {
            kernel::backward(&z[at..][..o.len()], &g[at..][..o.len()], omega, o)
        });
        FlexTensor::from_data(TensorData::new(out, shape))
    }
}

#[derive(Debug)]
struct SineBackward;

impl<B: Backend + ScaledSineOps> Backward<B, 1> for SineBackward {
    type State = (FloatTensor<B>, f32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [z_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (z, omega) = ops.state;
        if let Some(node) = z_node {
            grads.register::<B>(node.id, B::scaled_sin_backward(z, grad, omega));
        }
    }
}

impl<B: Backend + ScaledSineOps, C: CheckpointStrategy> ScaledSineOps for Autodiff<B, C> {
    fn scaled_sin(z: FloatTensor<Self>, omega: f32) -> FloatTensor<Self> {
        match SineBackward
            .prepare::<C>([z.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let z = z.into_primitive();
                let y = B::scaled_sin(z.clone(), omega);
                prep.finish((z, omega), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::scaled_sin(z.into_primitive(), omega)),
        }
    }

    fn scaled_sin_backward(
        z: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        omega: f32,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::scaled_sin_backward(
            z.into_primitive(),
            grad.into_primitive(),
            omega,
        ))
    }
}

/// `sin(ω·z)`: the op on Flex (with or without autodiff), ordinary tensor ops elsewhere.
pub fn scaled_sin<const D: usize>(z: Tensor<D>, omega: f32) -> Tensor<D> {
    let flex = matches!(z.device().inner().as_dispatch(), DispatchDevice::Flex(_));
    if !flex {
        return z.mul_scalar(omega).sin();
    }
    Tensor::from_dispatch(<Dispatch as ScaledSineOps>::scaled_sin(
        z.into_dispatch(),
        omega,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn kernels_match_libm() {
        let xs: Vec<f32> = (-400_000..=400_000).map(|i| i as f32 * 5e-4).collect();
        let ones = vec![1.0; xs.len()];
        let s = filled(xs.len(), |at, o| {
            kernel::forward(&xs[at..][..o.len()], 1.0, o)
        });
        let c = filled(xs.len(), |at, o| {
            kernel::backward(&xs[at..][..o.len()], &ones[at..][..o.len()], 1.0, o)
        });
        let mut worst = 0.0f32;
        for ((x, s), c) in xs.iter().zip(&s).zip(&c) {
            worst = worst.max((s - x.sin()).abs()).max((c - x.cos()).abs());
        }
        assert!(worst < 2e-6, "worst absolute error {worst} on [-200, 200]");
        assert!(kernel::sin(f32::NAN).is_nan() && kernel::cos(f32::INFINITY).is_nan());
    }

    /// Against `z·ω → sin` in Burn's own ops, under autodiff: value and gradient.
    #[test]
    fn op_matches_burn_ops_in_value_and_gradient() {
        let d = Device::flex().autodiff();
        d.seed(5);
        let z = Tensor::<2>::random([37, 129], Distribution::Uniform(-2.0, 2.0), &d).require_grad();
        let probe = Tensor::<2>::random([37, 129], Distribution::Default, &d);
        let y = scaled_sin(z.clone(), 30.0);
        let y_ref = z.clone().mul_scalar(30.0).sin();
        let err = (y.clone() - y_ref.clone()).abs().max().into_scalar::<f32>();
        assert!(err < 1e-5, "value {err}");
        let g = z.grad(&(y * probe.clone()).sum().backward()).unwrap();
        let g_ref = z.grad(&(y_ref * probe).sum().backward()).unwrap();
        let err = (g - g_ref).abs().max().into_scalar::<f32>();
        assert!(err < 1e-4, "gradient {err} (ω = 30 scales it up to 30)");
    }
}
