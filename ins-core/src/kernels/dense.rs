//! A dense layer `x·W + b` as one Flex op with its own backward, through the `gemm` crate.
//!
//! Flex's matmul zero-fills and copies each output, and the layer adds its bias in another
//! pass: about a tenth of a SIREN step went to `memset` and `memmove`. Here each result is
//! written once, the bias first and the product accumulated onto it (`super::flex`); the
//! backward reads the operands through strides instead of transposed copies. Other backends
//! take Burn's matmul ([`dense`] picks; a trained layer's rows in blocks, [`dense_blocks`]).

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, DispatchDevice, Flex, TensorMetadata,
    backend_extension,
};
use burn::nn::Linear;
use burn::prelude::*;

use crate::kernels::dense_bf16;
use crate::kernels::dense_blocks::trained_affine;
use crate::kernels::flex::{product, values as slice, written};

/// The dense layer and its gradients as backend operations (`W` in Burn's `[in, out]` layout).
#[backend_extension(Flex, Autodiff)]
pub trait DenseOps: Backend {
    /// `x [N, I]`, `w [I, O]`, `b [O]` → `x·w + b` `[N, O]`.
    fn dense(x: FloatTensor<Self>, w: FloatTensor<Self>, b: FloatTensor<Self>)
    -> FloatTensor<Self>;
    /// `g·wᵀ` `[N, I]` for `g [N, O]`.
    fn dense_grad_input(g: FloatTensor<Self>, w: FloatTensor<Self>) -> FloatTensor<Self>;
    /// `xᵀ·g` `[I, O]`.
    fn dense_grad_weight(x: FloatTensor<Self>, g: FloatTensor<Self>) -> FloatTensor<Self>;
}

fn contiguous(t: &FlexTensor) -> FlexTensor {
    assert_eq!(t.dtype(), DType::F32, "the dense op runs in f32");
    crate::kernels::flex::contiguous(t)
}

impl DenseOps for Flex {
    fn dense(x: FlexTensor, w: FlexTensor, b: FlexTensor) -> FlexTensor {
        let (x, w, b) = (contiguous(&x), contiguous(&w), contiguous(&b));
        let ([n, i], [wi, o]) = (dims(&x), dims(&w));
        assert_eq!(i, wi, "dense: input width {i}, weight rows {wi}");
        let (x, w, b) = (slice(&x), slice(&w), slice(&b));
        if dense_bf16::active() && dense_bf16::worth_it(o) && n > 0 {
            return tensor(dense_bf16::forward(x, w, b, [n, i, o]), [n, o]);
        }
        // SAFETY: the bias fills every row, then the product accumulates onto it; x is
        // [n, i], w is [i, o], dst is [n, o], all row-major.
        unsafe {
            written([n, o], |dst| {
                for r in 0..n {
                    std::ptr::copy_nonoverlapping(b.as_ptr(), dst.add(r * o), o);
                }
                product(
                    [n, i, o],
                    dst,
                    true,
                    1.0,
                    (x.as_ptr(), [i as isize, 1]),
                    (w.as_ptr(), [o as isize, 1]),
                )
            })
        }
    }

    fn dense_grad_input(g: FlexTensor, w: FlexTensor) -> FlexTensor {
        let (g, w) = (contiguous(&g), contiguous(&w));
        let ([n, o], [i, _]) = (dims(&g), dims(&w));
        let (g, w) = (slice(&g), slice(&w));
        if dense_bf16::active() && dense_bf16::worth_it(i) && n > 0 {
            return tensor(dense_bf16::grad_input(g, w, [n, o, i]), [n, i]);
        }
        // g [n, o] · wᵀ: w is [i, o] row-major, so wᵀ [o, i] has strides (1, o).
        // SAFETY: a GEMM writes all of dst [n, i].
        unsafe {
            written([n, i], |dst| {
                product(
                    [n, o, i],
                    dst,
                    false,
                    1.0,
                    (g.as_ptr(), [o as isize, 1]),
                    (w.as_ptr(), [1, o as isize]),
                )
            })
        }
    }

    fn dense_grad_weight(x: FlexTensor, g: FlexTensor) -> FlexTensor {
        let (x, g) = (contiguous(&x), contiguous(&g));
        let ([n, i], [_, o]) = (dims(&x), dims(&g));
        let (x, g) = (slice(&x), slice(&g));
        // The sum over rows gains at every width (6.9 against 14.4 ms for 16 columns).
        if dense_bf16::active() && n > 0 && o > 0 {
            return tensor(dense_bf16::grad_weight(x, g, [n, i, o]), [i, o]);
        }
        // xᵀ [i, n] has strides (1, i); g is [n, o].
        // SAFETY: a GEMM writes all of dst [i, o].
        unsafe {
            written([i, o], |dst| {
                product(
                    [i, n, o],
                    dst,
                    false,
                    1.0,
                    (x.as_ptr(), [1, i as isize]),
                    (g.as_ptr(), [o as isize, 1]),
                )
            })
        }
    }
}

fn tensor(values: Vec<f32>, shape: [usize; 2]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

fn dims(t: &FlexTensor) -> [usize; 2] {
    let s = t.shape();
    [s[0], s[1]]
}

#[derive(Debug)]
struct DenseBackward;

impl<B: Backend + DenseOps> Backward<B, 3> for DenseBackward {
    /// The input (for the weight gradient), the weight (for the input gradient) and whether
    /// the forward's product ran in bf16 (the gradients' do too).
    type State = (FloatTensor<B>, FloatTensor<B>, bool);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node, w_node, b_node] = ops.parents;
        let g = grads.consume::<B>(&ops.node);
        let (x, w, bf16) = ops.state;
        let _precision = dense_bf16::scope(bf16);
        if let Some(node) = b_node {
            let out = w.shape()[1];
            let db = B::float_reshape(B::float_sum_dim(g.clone(), 0), [out].into());
            grads.register::<B>(node.id, db);
        }
        if let Some(node) = w_node {
            grads.register::<B>(node.id, B::dense_grad_weight(x, g.clone()));
        }
        if let Some(node) = x_node {
            grads.register::<B>(node.id, B::dense_grad_input(g, w));
        }
    }
}

impl<B: Backend + DenseOps, C: CheckpointStrategy> DenseOps for Autodiff<B, C> {
    fn dense(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        match DenseBackward
            .prepare::<C>([x.node(), w.node(), b.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (x, w) = (x.into_primitive(), w.into_primitive());
                let y = B::dense(x.clone(), w.clone(), b.into_primitive());
                prep.finish((x, w, dense_bf16::active()), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::dense(
                x.into_primitive(),
                w.into_primitive(),
                b.into_primitive(),
            )),
        }
    }

    fn dense_grad_input(g: FloatTensor<Self>, w: FloatTensor<Self>) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::dense_grad_input(
            g.into_primitive(),
            w.into_primitive(),
        ))
    }

    fn dense_grad_weight(x: FloatTensor<Self>, g: FloatTensor<Self>) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::dense_grad_weight(
            x.into_primitive(),
            g.into_primitive(),
        ))
    }
}

/// `layer.forward(x)` for `x [N, in]`: through the op on Flex (with or without autodiff),
/// through Burn's `Linear` elsewhere.
pub fn dense(layer: &Linear, x: Tensor<2>) -> Tensor<2> {
    let w = layer.weight.val();
    let b = match &layer.bias {
        Some(b) => b.val(),
        None => Tensor::zeros([w.dims()[1]], &w.device()),
    };
    dense_with(x, w, b)
}

/// `x [N, I]·w [I, O] + b [O]` for any weight and bias (a part of a layer's, or a bias that
/// folds in what is constant over the rows): the op on Flex, a matmul elsewhere (by blocks of
/// rows where the weight is trained: [`dense_blocks`]).
pub fn dense_with(x: Tensor<2>, w: Tensor<2>, b: Tensor<1>) -> Tensor<2> {
    let flex = matches!(x.device().inner().as_dispatch(), DispatchDevice::Flex(_));
    if !flex {
        return trained_affine(x, w, Some(b));
    }
    Tensor::from_dispatch(<Dispatch as DenseOps>::dense(
        x.into_dispatch(),
        w.into_dispatch(),
        b.into_dispatch(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;
    use burn::tensor::Distribution;

    fn worst(a: Tensor<2>, b: Tensor<2>) -> f32 {
        let scale = b.clone().abs().max().into_scalar::<f32>().max(1e-6);
        (a - b).abs().max().into_scalar::<f32>() / scale
    }

    /// Against Burn's `Linear` under autodiff, on odd widths: value and the gradients of the
    /// input, the weight and the bias.
    #[test]
    fn matches_burn_linear_in_value_and_all_gradients() {
        let d = Device::flex().autodiff();
        d.seed(11);
        for (n, i, o, bias) in [(37, 129, 61, true), (300, 2, 256, true), (5, 17, 3, false)] {
            let layer = LinearConfig::new(i, o).with_bias(bias).init(&d);
            let x = Tensor::<2>::random([n, i], Distribution::Default, &d).require_grad();
            let probe = Tensor::<2>::random([n, o], Distribution::Default, &d);
            let y = dense(&layer, x.clone());
            let y_ref = layer.forward(x.clone());
            assert!(worst(y.clone(), y_ref.clone()) < 1e-5, "value {n}×{i}→{o}");
            let g = (y * probe.clone()).sum().backward();
            let g_ref = (y_ref * probe).sum().backward();
            let what = format!("{n}×{i}→{o}");
            assert!(
                worst(x.grad(&g).unwrap(), x.grad(&g_ref).unwrap()) < 1e-5,
                "dx {what}"
            );
            let w = layer.weight.val();
            assert!(
                worst(w.grad(&g).unwrap(), w.grad(&g_ref).unwrap()) < 1e-5,
                "dw {what}"
            );
            if let Some(b) = &layer.bias {
                let (db, db_ref) = (b.val().grad(&g).unwrap(), b.val().grad(&g_ref).unwrap());
                let err = (db - db_ref).abs().max().into_scalar::<f32>();
                assert!(err < 1e-4, "db {what}: {err}");
            }
        }
    }
}
