//! VGG's 2×2 max pool (stride 2, no padding) as a Flex op with its own backward.
//!
//! Flex's pool is general (any window, stride, padding, dilation; 3-D underneath): its forward
//! stores an `i64` index per output, and its backward zero-fills the input's gradient and then
//! adds each output's gradient at its index, one bounds-checked scalar at a time: about a
//! twelfth of a `vgg` step. Here the forward keeps no indices (the backward finds each window's
//! maximum again in the input, which the ReLU before the pool keeps alive anyway), and the
//! backward writes every value of the input's gradient once. The window's maximum is picked as
//! Flex picks it, so values and gradients are the same bit for bit, ties and NaN included.

#![allow(deprecated)]

use crate::op::{tensor, values};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, Flex, TensorMetadata, backend_extension,
};
use burn::prelude::*;
use burn::tensor::module::max_pool2d;
use burn::tensor::ops::MaxPoolOptions;
use rayon::prelude::*;

/// Whether a window's scan moves its maximum from `m` to the next value `x`, as Flex's does:
/// where `x` is larger or NaN (so the first of equal values stays, and the last NaN).
#[inline(always)]
fn moves(m: f32, x: f32) -> bool {
    x > m || x.is_nan()
}

/// Each window's maximum and its place in the window (row-major: 0 top left, 1 top right,
/// 2 bottom left, 3 bottom right), for the windows of two rows `top` and `bottom`. Selects,
/// not branches: which place holds a maximum is data, and branching on it mispredicted so
/// often that a scalar loop took a tenth of a `vgg` step; this one runs many lanes at a time.
#[inline(always)]
fn scan(t: &[f32], b: &[f32]) -> (f32, u32) {
    let (mut m, mut k) = (t[0], 0);
    for (place, x) in [(1, t[1]), (2, b[0]), (3, b[1])] {
        let go = moves(m, x);
        m = if go { x } else { m };
        k = if go { place } else { k };
    }
    (m, k)
}

/// The two input rows under output row `r` of a `[h, w]` plane, each cut to the `2·wo`
/// values the windows cover.
fn rows(plane: &[f32], w: usize, wo: usize, r: usize) -> (&[f32], &[f32]) {
    (
        &plane[2 * r * w..][..2 * wo],
        &plane[(2 * r + 1) * w..][..2 * wo],
    )
}

/// The output's height and width: a last odd row or column is dropped, as by Flex.
fn pooled([h, w]: [usize; 2]) -> [usize; 2] {
    [h / 2, w / 2]
}

/// `x [planes, h, w]` → `[planes, h/2, w/2]`, each value its window's maximum.
pub fn forward(x: &[f32], [planes, h, w]: [usize; 3]) -> Vec<f32> {
    assert_eq!(x.len(), planes * h * w, "max pool: input of the wrong size");
    let [ho, wo] = pooled([h, w]);
    let mut out = vec![0.0f32; planes * ho * wo];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(ho * wo)
        .zip(x.par_chunks(h * w))
        .for_each(|(o, plane)| {
            for (r, o) in o.chunks_exact_mut(wo).enumerate() {
                let (top, bottom) = rows(plane, w, wo, r);
                for ((o, t), b) in o
                    .iter_mut()
                    .zip(top.chunks_exact(2))
                    .zip(bottom.chunks_exact(2))
                {
                    *o = scan(t, b).0;
                }
            }
        });
    out
}

/// `∂L/∂x [planes, h, w]` from the input and `∂L/∂y [planes, h/2, w/2]`: each output's
/// gradient at its window's maximum, zero elsewhere (and on a dropped last row or column).
pub fn backward(x: &[f32], grad: &[f32], [planes, h, w]: [usize; 3]) -> Vec<f32> {
    let [ho, wo] = pooled([h, w]);
    assert_eq!(x.len(), planes * h * w, "max pool: input of the wrong size");
    assert_eq!(
        grad.len(),
        planes * ho * wo,
        "max pool: gradient of the wrong size"
    );
    let mut out = vec![0.0f32; planes * h * w];
    if out.is_empty() || ho * wo == 0 {
        return out;
    }
    out.par_chunks_mut(h * w)
        .zip(x.par_chunks(h * w))
        .zip(grad.par_chunks(ho * wo))
        .for_each(|((o, plane), g)| {
            for (r, g) in g.chunks_exact(wo).enumerate() {
                let (top, bottom) = rows(plane, w, wo, r);
                let (ot, ob) = o[2 * r * w..(2 * r + 2) * w].split_at_mut(w);
                let windows = top.chunks_exact(2).zip(bottom.chunks_exact(2));
                let outs = ot.chunks_exact_mut(2).zip(ob.chunks_exact_mut(2));
                for (((t, b), (ot, ob)), &g) in windows.zip(outs).zip(g) {
                    let k = scan(t, b).1;
                    ot[0] = if k == 0 { g } else { 0.0 };
                    ot[1] = if k == 1 { g } else { 0.0 };
                    ob[0] = if k == 2 { g } else { 0.0 };
                    ob[1] = if k == 3 { g } else { 0.0 };
                }
            }
        });
    out
}

/// The pool and its input gradient as backend operations.
#[backend_extension(Flex, Autodiff)]
pub trait MaxPoolOps: Backend {
    /// `x [B, C, H, W]` → `[B, C, H/2, W/2]`.
    fn ins_max_pool_2x2(x: FloatTensor<Self>) -> FloatTensor<Self>;
    /// `∂L/∂x [B, C, H, W]` for the pool's input `x` and `grad [B, C, H/2, W/2]`.
    fn ins_max_pool_2x2_grad(x: FloatTensor<Self>, grad: FloatTensor<Self>) -> FloatTensor<Self>;
}

/// `[planes, h, w]` of a `[B, C, H, W]` tensor.
fn planes(t: &impl TensorMetadata) -> [usize; 3] {
    let s = t.shape();
    [s[0] * s[1], s[2], s[3]]
}

impl MaxPoolOps for Flex {
    fn ins_max_pool_2x2(x: FlexTensor) -> FlexTensor {
        let (s, p) = (x.shape(), planes(&x));
        let [ho, wo] = pooled([p[1], p[2]]);
        tensor(values(&x, |x| forward(x, p)), [s[0], s[1], ho, wo])
    }

    fn ins_max_pool_2x2_grad(x: FlexTensor, grad: FlexTensor) -> FlexTensor {
        let (s, p) = (x.shape(), planes(&x));
        let g = values(&x, |x| values(&grad, |grad| backward(x, grad, p)));
        tensor(g, [s[0], s[1], s[2], s[3]])
    }
}

#[derive(Debug)]
struct MaxPoolBackward;

impl<B: Backend + MaxPoolOps> Backward<B, 1> for MaxPoolBackward {
    /// The pool's input: the backward finds each window's maximum in it again.
    type State = FloatTensor<B>;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        if let Some(node) = x_node {
            grads.register::<B>(node.id, B::ins_max_pool_2x2_grad(ops.state, grad));
        }
    }
}

impl<B: Backend + MaxPoolOps, C: CheckpointStrategy> MaxPoolOps for Autodiff<B, C> {
    fn ins_max_pool_2x2(x: FloatTensor<Self>) -> FloatTensor<Self> {
        match MaxPoolBackward
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let x = x.into_primitive();
                let y = B::ins_max_pool_2x2(x.clone());
                prep.finish(x, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::ins_max_pool_2x2(x.into_primitive())),
        }
    }

    fn ins_max_pool_2x2_grad(x: FloatTensor<Self>, grad: FloatTensor<Self>) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ins_max_pool_2x2_grad(
            x.into_primitive(),
            grad.into_primitive(),
        ))
    }
}

/// 2×2 max pool with stride 2 of `x [B, C, H, W]`: through the op on Flex (with or without
/// autodiff), through Burn's `max_pool2d` elsewhere and for other float types.
pub fn max_pool_2x2(x: Tensor<4>) -> Tensor<4> {
    if !crate::kernel_device(&x.device()) || x.dtype() != DType::F32 {
        return max_pool2d(x, MaxPoolOptions::new([2, 2]).with_stride([2, 2]));
    }
    Tensor::from_dispatch(<Dispatch as MaxPoolOps>::ins_max_pool_2x2(
        x.into_dispatch(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host(t: Tensor<4>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// Against Flex's own pool under autodiff, bit for bit: values and the input's gradient,
    /// on odd sizes (a dropped last row and column), with ties (ReLU's zeros, repeated values)
    /// and NaN in some windows.
    #[test]
    fn matches_flex_pool_in_value_and_gradient_bit_for_bit() {
        let d = Device::flex().autodiff();
        d.seed(2);
        for [b, c, h, w] in [[2, 3, 9, 7], [1, 70, 16, 16], [1, 1, 3, 5]] {
            let n = b * c * h * w;
            let mut v: Vec<f32> = (0..n)
                .map(|i| ((i * 7919 % 13) as f32 - 6.0).max(0.0) * 0.25)
                .collect();
            v.iter_mut().step_by(17).for_each(|x| *x = f32::NAN);
            let x = || {
                Tensor::<4>::from_data(TensorData::new(v.clone(), [b, c, h, w]), &d).require_grad()
            };
            let probe = Tensor::<4>::random(
                [b, c, h / 2, w / 2],
                burn::tensor::Distribution::Default,
                &d,
            );
            let (xa, xb) = (x(), x());
            let ours = max_pool_2x2(xa.clone());
            let flex = max_pool2d(xb.clone(), MaxPoolOptions::new([2, 2]).with_stride([2, 2]));
            let bits = |t: Vec<f32>| t.into_iter().map(f32::to_bits).collect::<Vec<_>>();
            assert_eq!(
                bits(host(ours.clone())),
                bits(host(flex.clone())),
                "values {b}×{c}×{h}×{w}"
            );
            let ga = (ours * probe.clone()).sum().backward();
            let gb = (flex * probe).sum().backward();
            assert_eq!(
                bits(host(xa.grad(&ga).unwrap())),
                bits(host(xb.grad(&gb).unwrap())),
                "gradients {b}×{c}×{h}×{w}"
            );
        }
    }

    /// The plain kernels on a window each of whose places holds the maximum once.
    #[test]
    fn each_place_of_the_window_can_be_the_maximum() {
        for k in 0..4 {
            let mut x = [0.0f32; 4];
            x[k] = 1.0;
            assert_eq!(forward(&x, [1, 2, 2]), vec![1.0]);
            let g = backward(&x, &[3.0], [1, 2, 2]);
            let want: Vec<f32> = (0..4).map(|i| if i == k { 3.0 } else { 0.0 }).collect();
            assert_eq!(g, want, "maximum at {k}");
        }
    }
}
