//! Picking entries along one dimension of a tracked tensor (`select`'s result), with a backward
//! that suits the backend.
//!
//! Burn's `select` back-propagates through `select_assign`, which the CubeCL backends run as
//! one GPU thread per entry of the other dimensions, each walking every index in turn: picking
//! a NeRF step's ~130,000 marched samples into its padded `[rays, width]` layout left 1 to 3
//! threads of an H200 looping over half a million indices, about 60 ms per pick and most of a
//! 480 ms step (CubeCL's kernel profile, docs/measurements.md). `gather` back-propagates
//! through `scatter`, which those backends run as one atomic add per entry, all at once.
//!
//! On Flex the opposite holds: its `gather` and `scatter` walk every entry through a general
//! N-d index (and the indices are expanded to the picked tensor's whole shape first), while
//! `select` along the first dimension of a matrix copies whole rows. There the pick is such a
//! row select, the leading dimensions folded into the row index.

use crate::kernels::flex::is_flex;
use burn::prelude::*;

/// `tensor.select(dim, index)`, computed the way the backend back-propagates fastest (see the
/// module). `index` `[K]` picks along `dim`; the result has `K` there and `tensor`'s other
/// sizes.
pub fn select_parallel<const D: usize>(
    tensor: Tensor<D>,
    dim: usize,
    index: Tensor<1, Int>,
) -> Tensor<D> {
    if is_flex(&tensor.device()) {
        select_rows(tensor, dim, index)
    } else {
        select_by_gather(tensor, dim, index)
    }
}

/// The pick as a `gather`, whose backward is a parallel `scatter` (the GPU backends).
fn select_by_gather<const D: usize>(
    tensor: Tensor<D>,
    dim: usize,
    index: Tensor<1, Int>,
) -> Tensor<D> {
    let mut shape = tensor.dims();
    let k = index.dims()[0];
    let mut lone = [1usize; D];
    lone[dim] = k;
    shape[dim] = k;
    let indices = index.reshape(lone).expand(shape);
    tensor.gather(dim, indices)
}

/// The pick as a row `select` of a matrix (Flex): `tensor` seen as `[L·n, rest]`, `L` the
/// product of the sizes before `dim`, `n` its size at `dim`, and the rows `l·n + index[k]`.
fn select_rows<const D: usize>(tensor: Tensor<D>, dim: usize, index: Tensor<1, Int>) -> Tensor<D> {
    let shape = tensor.dims();
    let k = index.dims()[0];
    let leading: usize = shape[..dim].iter().product();
    let n = shape[dim];
    let rest: usize = shape[dim + 1..].iter().product();
    let rows = if leading == 1 {
        index
    } else {
        let device = index.device();
        let starts = Tensor::<1, Int>::arange(0..leading as i64, &device).mul_scalar(n as i64);
        (starts.reshape([leading, 1]) + index.reshape([1, k])).reshape([leading * k])
    };
    let mut picked = shape;
    picked[dim] = k;
    tensor
        .reshape([leading * n, rest])
        .select(0, rows)
        .reshape(picked)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// Both ways of picking, along each dimension of a 3-d tensor, give `select`'s values and
    /// gradients; an index used twice and one never included.
    #[test]
    fn equals_select_in_value_and_gradient() {
        let device = Device::flex().autodiff();
        type Pick = fn(Tensor<3>, usize, Tensor<1, Int>) -> Tensor<3>;
        let picks: [(&str, Pick); 2] = [("gather", select_by_gather), ("rows", select_rows)];
        for (name, pick) in picks {
            for dim in 0..3 {
                let mut shape = [2, 5, 3];
                shape[dim] = 5;
                let x = Tensor::<3>::random(shape, Distribution::Default, &device).require_grad();
                let index = Tensor::<1, Int>::from_ints([4, 0, 0, 2, 3, 4], &device);
                let mut picked = shape;
                picked[dim] = 6;
                let w = Tensor::<3>::random(picked, Distribution::Default, &device);
                let a = x.clone().select(dim, index.clone());
                let b = pick(x.clone(), dim, index);
                let max_diff =
                    |p: Tensor<3>, q: Tensor<3>| (p - q).abs().max().into_scalar::<f32>();
                assert_eq!(max_diff(a.clone(), b.clone()), 0.0, "{name} along {dim}");
                let ga = x.grad(&(a * w.clone()).sum().backward()).unwrap();
                let gb = x.grad(&(b * w).sum().backward()).unwrap();
                let d = (ga.clone() - gb).abs().max().into_scalar::<f32>();
                assert!(d < 1e-6, "{name} along {dim}: gradients differ by {d}");
                // Entry 1 is never picked: no gradient; entry 0, picked twice, gets two.
                let never = ga.narrow(dim, 1, 1).abs().sum().into_scalar::<f32>();
                assert_eq!(never, 0.0, "{name} along {dim}");
            }
        }
    }
}
