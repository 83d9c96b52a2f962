//! The Gram matrix `G = s·F Fᵀ` as one Flex op with its own backward, `dF = s·(dG + dGᵀ)·F`.
//!
//! Built from tensor ops, `F` enters the product twice (once transposed), so autodiff sums two
//! gradients, one of them a transposed view that Flex adds element by element through strides:
//! an eighth of a `vgg` step. Here the backward is one GEMM with the small symmetrised `dG`.

#![allow(deprecated)]

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

use crate::kernels::flex::{product, product_on, values, written, written_vec};

/// The Gram matrix and its gradient as backend operations.
#[backend_extension(Flex, Autodiff)]
pub trait GramOps: Backend {
    /// `f [B, C, P]` → `scale · f fᵀ` `[B, C, C]`.
    fn gram(f: FloatTensor<Self>, scale: f32) -> FloatTensor<Self>;
    /// `scale · (g + gᵀ) · f` `[B, C, P]` for `g [B, C, C]`.
    fn gram_backward(g: FloatTensor<Self>, f: FloatTensor<Self>, scale: f32) -> FloatTensor<Self>;
}

fn contiguous(t: &FlexTensor) -> FlexTensor {
    assert_eq!(t.dtype(), DType::F32, "the Gram op runs in f32");
    t.to_contiguous()
}

fn dims(t: &FlexTensor) -> [usize; 3] {
    let s = t.shape();
    [s[0], s[1], s[2]]
}

impl GramOps for Flex {
    fn gram(f: FlexTensor, scale: f32) -> FlexTensor {
        let f = contiguous(&f);
        let [b, c, p] = dims(&f);
        let f = values(&f);
        let shares = rayon::current_num_threads().min(p / MIN_COLUMNS_A_SHARE);
        if shares > 1 {
            return split_sum(f, [b, c, p], scale, shares);
        }
        // SAFETY: one GEMM per batch writes all of its [c, c] block; f [b, c, p] is row-major,
        // so its transpose [p, c] has strides (1, p).
        unsafe {
            written([b, c, c], |dst| {
                for i in 0..b {
                    let fi = f[i * c * p..].as_ptr();
                    product(
                        [c, p, c],
                        dst.add(i * c * c),
                        false,
                        scale,
                        (fi, [p as isize, 1]),
                        (fi, [1, p as isize]),
                    );
                }
            })
        }
    }

    fn gram_backward(g: FlexTensor, f: FlexTensor, scale: f32) -> FlexTensor {
        let (g, f) = (contiguous(&g), contiguous(&f));
        let [b, c, p] = dims(&f);
        let (g, f) = (values(&g), values(&f));
        // The symmetrised gradient: small (c × c per batch).
        let sym: Vec<f32> = (0..b * c * c)
            .map(|at| {
                let (i, r, k) = (at / (c * c), at / c % c, at % c);
                g[at] + g[i * c * c + k * c + r]
            })
            .collect();
        // SAFETY: one GEMM per batch writes all of its [c, p] block.
        unsafe {
            written([b, c, p], |dst| {
                for i in 0..b {
                    product(
                        [c, c, p],
                        dst.add(i * c * p),
                        false,
                        scale,
                        (sym[i * c * c..].as_ptr(), [c as isize, 1]),
                        (f[i * c * p..].as_ptr(), [p as isize, 1]),
                    );
                }
            })
        }
    }
}

/// Columns a thread's share of a Gram's sum takes at least. A Gram's output is small (`[c, c]`)
/// and its sum long (`p` columns): the `gemm` crate splits only the output between threads,
/// and a 64 × 64 Gram over 16,384 columns ran at about a fifth of its speed, 5.2 ms (VGG's
/// relu1_2 in a SIREN stylizing step, 2-core Zen 4).
const MIN_COLUMNS_A_SHARE: usize = 1024;

/// `scale · f fᵀ` with the columns split into `shares` consecutive ranges, each range's product
/// on a thread of its own, the partial Grams then added in the ranges' order.
fn split_sum(f: &[f32], [b, c, p]: [usize; 3], scale: f32, shares: usize) -> FlexTensor {
    use rayon::prelude::*;
    let mut out = Vec::with_capacity(b * c * c);
    for i in 0..b {
        let fi = &f[i * c * p..(i + 1) * c * p];
        let partials: Vec<Vec<f32>> = (0..shares)
            .into_par_iter()
            .map(|s| {
                let (start, end) = (s * p / shares, (s + 1) * p / shares);
                let at = fi[start..].as_ptr();
                // SAFETY: one GEMM writes all of the [c, c] partial from columns start..end of
                // f's rows (strides p, 1) and of its transpose (1, p).
                unsafe {
                    written_vec(c * c, |dst| {
                        product_on(
                            gemm::Parallelism::None,
                            [c, end - start, c],
                            dst,
                            false,
                            scale,
                            (at, [p as isize, 1]),
                            (at, [1, p as isize]),
                        )
                    })
                }
            })
            .collect();
        let mut partials = partials.into_iter();
        let mut sum = partials.next().expect("at least one share");
        for part in partials {
            sum.iter_mut().zip(&part).for_each(|(a, b)| *a += b);
        }
        out.extend_from_slice(&sum);
    }
    FlexTensor::from_data(TensorData::new(out, [b, c, c]))
}

#[derive(Debug)]
struct GramBackward;

impl<B: Backend + GramOps> Backward<B, 1> for GramBackward {
    type State = (FloatTensor<B>, f32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [f_node] = ops.parents;
        let g = grads.consume::<B>(&ops.node);
        let (f, scale) = ops.state;
        if let Some(node) = f_node {
            grads.register::<B>(node.id, B::gram_backward(g, f, scale));
        }
    }
}

impl<B: Backend + GramOps, C: CheckpointStrategy> GramOps for Autodiff<B, C> {
    fn gram(f: FloatTensor<Self>, scale: f32) -> FloatTensor<Self> {
        match GramBackward
            .prepare::<C>([f.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let f = f.into_primitive();
                let y = B::gram(f.clone(), scale);
                prep.finish((f, scale), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gram(f.into_primitive(), scale)),
        }
    }

    fn gram_backward(g: FloatTensor<Self>, f: FloatTensor<Self>, scale: f32) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::gram_backward(
            g.into_primitive(),
            f.into_primitive(),
            scale,
        ))
    }
}

/// `scale · f fᵀ` for `f [B, C, P]` through the op (Flex, with or without autodiff).
pub fn gram_flex(f: Tensor<3>, scale: f32) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as GramOps>::gram(f.into_dispatch(), scale))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    fn worst<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> f32 {
        let scale = b.clone().abs().max().into_scalar::<f32>().max(1e-6);
        (a - b).abs().max().into_scalar::<f32>() / scale
    }

    /// Against the product of tensor ops under autodiff, on odd shapes: value and gradient
    /// (through a non-symmetric probe, so that both halves of the gradient count).
    #[test]
    fn matches_tensor_ops_in_value_and_gradient() {
        let d = Device::flex().autodiff();
        d.seed(5);
        for [b, c, p] in [[1, 3, 7], [2, 17, 129], [1, 64, 1000], [2, 9, 3001]] {
            let f = Tensor::<3>::random([b, c, p], Distribution::Default, &d).require_grad();
            let probe = Tensor::<3>::random([b, c, c], Distribution::Default, &d);
            let scale = 1.0 / (c * p) as f32;
            let g = gram_flex(f.clone(), scale);
            let g_ref = f
                .clone()
                .matmul(f.clone().swap_dims(1, 2))
                .mul_scalar(scale);
            assert!(worst(g.clone(), g_ref.clone()) < 1e-5, "value {b}×{c}×{p}");
            let grads = (g * probe.clone()).sum().backward();
            let grads_ref = (g_ref * probe).sum().backward();
            let err = worst(f.grad(&grads).unwrap(), f.grad(&grads_ref).unwrap());
            assert!(err < 1e-5, "gradient {b}×{c}×{p}: {err}");
        }
    }
}
