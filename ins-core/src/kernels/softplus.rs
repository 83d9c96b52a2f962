//! Softplus `log(1 + e^{βx})/β` and its slope `σ(βx)` as Flex ops with their own backwards,
//! through vectorized `exp` and `log1p`.
//!
//! Burn builds softplus from eight tensor ops, and Flex runs its `exp` and `log1p` as libm
//! calls element by element: a third of an IDR pretraining step went to `log1pf` and `expf`.
//! The SDF networks use both ops: the value in the forward pass, the slope for the tangents of
//! the forward-mode normal. Other backends use Burn's ops ([`softplus`] and [`softplus_slope`]
//! pick).

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, Flex, TensorData, TensorMetadata,
    backend_extension,
};
use burn::prelude::*;

use crate::kernels::flex::{filled, on_flex};

/// The kernels, on `a = βx`, through `e = e^{−|a|}` (never overflows):
/// `softplus = max(a, 0) + log1p(e)`, `σ(a) = 1/(1+e)` for `a ≥ 0` and `e/(1+e)` below.
pub mod kernel {
    use std::mem::MaybeUninit;

    const LOG2E: f32 = std::f32::consts::LOG2_E;
    /// ln 2 split so that `k·LN2_HI` is exact for the integers `k` that occur (|k| ≤ 126).
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    /// Adding and subtracting 1.5·2²³ rounds to the nearest integer, in any SIMD width.
    const ROUND: f32 = 12_582_912.0;

    /// `e^{−|a|}`: `2^k · e^r` with `|r| ≤ ln2/2` and a degree-7 Taylor polynomial (relative
    /// error below 2·10⁻⁷). `|a|` is capped at 87, where the result (1.6·10⁻³⁸) is still normal.
    #[inline(always)]
    pub fn exp_neg_abs(a: f32) -> f32 {
        let t = -a.abs().min(87.0);
        let k = (t * LOG2E + ROUND) - ROUND;
        let r = (t - k * LN2_HI) - k * LN2_LO;
        let p = 1.0 / 5040.0;
        let p = p * r + 1.0 / 720.0;
        let p = p * r + 1.0 / 120.0;
        let p = p * r + 1.0 / 24.0;
        let p = p * r + 1.0 / 6.0;
        let p = p * r + 0.5;
        let p = p * r + 1.0;
        let p = p * r + 1.0;
        // 2^k through the exponent bits (k ∈ [−126, 0]).
        p * f32::from_bits(((k as i32 + 127) as u32) << 23)
    }

    /// `ln(1 + e)` for `e ∈ [0, 1]`: `2·atanh(s)` with `s = e/(2+e) ≤ 1/3`, its series to
    /// `s¹³` (relative error below 10⁻⁸ before rounding).
    #[inline(always)]
    pub fn log1p_unit(e: f32) -> f32 {
        let s = e / (2.0 + e);
        let s2 = s * s;
        let p = 1.0 / 13.0;
        let p = p * s2 + 1.0 / 11.0;
        let p = p * s2 + 1.0 / 9.0;
        let p = p * s2 + 1.0 / 7.0;
        let p = p * s2 + 1.0 / 5.0;
        let p = p * s2 + 1.0 / 3.0;
        let p = p * s2 + 1.0;
        2.0 * s * p
    }

    /// `log(1 + e^{βx})/β`.
    #[inline(always)]
    pub fn softplus(x: f32, beta: f32) -> f32 {
        let a = beta * x;
        let y = (a.max(0.0) + log1p_unit(exp_neg_abs(a))) / beta;
        // NaN stays NaN (`max` and `min` would drop it): a diverging run must be seen.
        if x.is_nan() { x } else { y }
    }

    /// `σ(βx)`.
    #[inline(always)]
    pub fn slope(x: f32, beta: f32) -> f32 {
        let a = beta * x;
        let e = exp_neg_abs(a);
        let inv = 1.0 / (1.0 + e);
        let y = if a >= 0.0 { inv } else { e * inv };
        if x.is_nan() { x } else { y }
    }

    /// What each op computes, on an input and, for the backwards, an incoming gradient.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Map {
        /// `softplus(x)`.
        Softplus,
        /// `σ(βx)`: the gradient of softplus, and the slope op's value.
        Slope,
        /// `β·σ(βx)·(1 − σ(βx))`: the slope op's gradient.
        SlopeGradient,
    }

    #[inline(always)]
    fn apply(map: Map, x: f32, beta: f32) -> f32 {
        match map {
            Map::Softplus => softplus(x, beta),
            Map::Slope => slope(x, beta),
            Map::SlopeGradient => {
                let s = slope(x, beta);
                beta * s * (1.0 - s)
            }
        }
    }

    /// One map over the slices. Indexed loops, not iterator adapters: a closure handed to
    /// `for_each` was compiled as a function of its own, outside the vectorized caller, and ran
    /// one lane at a time (a fifth of an IDR step).
    #[inline(always)]
    fn map_loop<const MAP: u8>(
        x: &[f32],
        g: Option<&[f32]>,
        beta: f32,
        out: &mut [MaybeUninit<f32>],
    ) {
        let map = match MAP {
            0 => Map::Softplus,
            1 => Map::Slope,
            _ => Map::SlopeGradient,
        };
        let n = out.len();
        let x = &x[..n];
        match g {
            None => {
                for i in 0..n {
                    out[i].write(apply(map, x[i], beta));
                }
            }
            Some(g) => {
                let g = &g[..n];
                for i in 0..n {
                    out[i].write(apply(map, x[i], beta) * g[i]);
                }
            }
        }
    }

    #[inline(always)]
    fn run_loop(map: Map, x: &[f32], g: Option<&[f32]>, beta: f32, out: &mut [MaybeUninit<f32>]) {
        match map {
            Map::Softplus => map_loop::<0>(x, g, beta, out),
            Map::Slope => map_loop::<1>(x, g, beta, out),
            Map::SlopeGradient => map_loop::<2>(x, g, beta, out),
        }
    }

    crate::kernels::flex::vectorized! {
        /// `out = map(x)` (times `g` where given).
        pub fn run(
            map: Map,
            x: &[f32],
            g: Option<&[f32]>,
            beta: f32,
            out: &mut [MaybeUninit<f32>],
        ) = run_loop;
    }
}

use kernel::Map;

/// The ops and their gradients as backend operations.
#[backend_extension(Flex, Autodiff)]
pub trait SoftplusOps: Backend {
    /// `map(x)` element-wise.
    fn softplus_map(x: FloatTensor<Self>, beta: f32, map: Map) -> FloatTensor<Self>;
    /// `map(x)·grad` element-wise (same shapes): a gradient.
    fn softplus_map_times(
        x: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        beta: f32,
        map: Map,
    ) -> FloatTensor<Self>;
}

/// `map(x)`, times `grad` where given, on Flex tensors.
fn run_flex(x: FlexTensor, grad: Option<FlexTensor>, beta: f32, map: Map) -> FlexTensor {
    assert_eq!(x.dtype(), DType::F32, "the softplus ops run in f32");
    let shape = x.shape();
    let x = x.to_contiguous();
    let x = x.as_slice::<f32>().expect("contiguous f32");
    let g = grad.map(|g| g.to_contiguous());
    let g = g
        .as_ref()
        .map(|g| g.as_slice::<f32>().expect("contiguous f32"));
    let out = filled(x.len(), |at, o| {
        kernel::run(
            map,
            &x[at..][..o.len()],
            g.map(|g| &g[at..][..o.len()]),
            beta,
            o,
        )
    });
    FlexTensor::from_data(TensorData::new(out, shape))
}

impl SoftplusOps for Flex {
    fn softplus_map(x: FlexTensor, beta: f32, map: Map) -> FlexTensor {
        run_flex(x, None, beta, map)
    }

    fn softplus_map_times(x: FlexTensor, grad: FlexTensor, beta: f32, map: Map) -> FlexTensor {
        run_flex(x, Some(grad), beta, map)
    }
}

/// The backward of `Softplus` (gradient `σ(βx)·g`) or `Slope` (gradient `β·σ(1−σ)·g`).
#[derive(Debug)]
struct MapBackward(Map);

impl<B: Backend + SoftplusOps> Backward<B, 1> for MapBackward {
    type State = (FloatTensor<B>, f32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (x, beta) = ops.state;
        let derivative = match self.0 {
            Map::Softplus => Map::Slope,
            Map::Slope => Map::SlopeGradient,
            Map::SlopeGradient => unreachable!("the slope's gradient is not differentiated"),
        };
        if let Some(node) = x_node {
            grads.register::<B>(node.id, B::softplus_map_times(x, grad, beta, derivative));
        }
    }
}

impl<B: Backend + SoftplusOps, C: CheckpointStrategy> SoftplusOps for Autodiff<B, C> {
    fn softplus_map(x: FloatTensor<Self>, beta: f32, map: Map) -> FloatTensor<Self> {
        assert!(
            map != Map::SlopeGradient,
            "only softplus and its slope are differentiable ops"
        );
        match MapBackward(map)
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let x = x.into_primitive();
                let y = B::softplus_map(x.clone(), beta, map);
                prep.finish((x, beta), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::softplus_map(x.into_primitive(), beta, map)),
        }
    }

    fn softplus_map_times(
        x: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        beta: f32,
        map: Map,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::softplus_map_times(
            x.into_primitive(),
            grad.into_primitive(),
            beta,
            map,
        ))
    }
}

fn mapped<const D: usize>(x: Tensor<D>, beta: f64, map: Map) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as SoftplusOps>::softplus_map(
        x.into_dispatch(),
        beta as f32,
        map,
    ))
}

/// `log(1 + e^{βx})/β`: the op on Flex (with or without autodiff), Burn's elsewhere.
pub fn softplus<const D: usize>(x: Tensor<D>, beta: f64) -> Tensor<D> {
    if !on_flex(&x) {
        return burn::tensor::activation::softplus(x, beta);
    }
    mapped(x, beta, Map::Softplus)
}

/// `σ(βx)`, the derivative of [`softplus`]: the op on Flex, Burn's sigmoid elsewhere.
pub fn softplus_slope<const D: usize>(x: Tensor<D>, beta: f64) -> Tensor<D> {
    if !on_flex(&x) {
        return burn::tensor::activation::sigmoid(x.mul_scalar(beta));
    }
    mapped(x, beta, Map::Slope)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// The kernels against libm (in f64) on β = 100 and x ∈ [−0.8, 3]: both tails, down to
    /// values of 10⁻³⁷ (f32's normal range ends just below).
    #[test]
    fn kernels_match_libm() {
        let beta = 100.0f32;
        let mut worst = [0.0f64; 2];
        for i in -80_000..=300_000 {
            let x = i as f32 * 1e-5;
            let a = (beta * x) as f64;
            let sp = (a.max(0.0) + (-a.abs()).exp().ln_1p()) / beta as f64;
            let s = 1.0 / (1.0 + (-a).exp());
            let e_sp = (kernel::softplus(x, beta) as f64 - sp).abs() / sp.max(1e-30);
            let e_s = (kernel::slope(x, beta) as f64 - s).abs() / s.max(1e-30);
            worst = [worst[0].max(e_sp), worst[1].max(e_s)];
        }
        assert!(
            worst[0] < 1e-6,
            "softplus: worst relative error {}",
            worst[0]
        );
        assert!(worst[1] < 1e-6, "slope: worst relative error {}", worst[1]);
        assert!(kernel::softplus(f32::NAN, beta).is_nan());
        assert!(kernel::slope(f32::NAN, beta).is_nan());
    }

    /// Against Burn's softplus and sigmoid under autodiff: value and gradient of both ops,
    /// the slope's through a second op, as the forward-mode normals use it.
    #[test]
    fn ops_match_burn_in_value_and_gradient() {
        let d = Device::flex().autodiff();
        d.seed(9);
        let x = Tensor::<2>::random([37, 129], Distribution::Uniform(-0.1, 0.1), &d).require_grad();
        let probe = Tensor::<2>::random([37, 129], Distribution::Default, &d);
        let pairs = [
            (
                softplus(x.clone(), 100.0),
                burn::tensor::activation::softplus(x.clone(), 100.0),
            ),
            (
                softplus_slope(x.clone(), 100.0),
                burn::tensor::activation::sigmoid(x.clone().mul_scalar(100.0)),
            ),
        ];
        for (k, (y, y_ref)) in pairs.into_iter().enumerate() {
            let err = (y.clone() - y_ref.clone()).abs().max().into_scalar::<f32>();
            assert!(err < 1e-6, "op {k}: value {err}");
            let g = x.grad(&(y * probe.clone()).sum().backward()).unwrap();
            let g_ref = x.grad(&(y_ref * probe.clone()).sum().backward()).unwrap();
            let scale = g_ref.clone().abs().max().into_scalar::<f32>();
            let err = (g - g_ref).abs().max().into_scalar::<f32>() / scale;
            assert!(err < 1e-5, "op {k}: gradient {err}");
        }
    }
}
