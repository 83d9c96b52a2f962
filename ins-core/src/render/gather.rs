//! Picking entries along one dimension of a tracked tensor (`select`'s result) with a backward
//! that runs in parallel on GPUs.
//!
//! Burn's `select` back-propagates through `select_assign`, which the CubeCL backends run as
//! one GPU thread per entry of the other dimensions, each walking every index in turn: picking
//! a NeRF step's ~130,000 marched samples into its padded `[rays, width]` layout left 1 to 3
//! threads of an H200 looping over half a million indices, about 60 ms per pick and most of a
//! 480 ms step (CubeCL's kernel profile, docs/measurements.md). `gather` back-propagates
//! through `scatter`, which those backends run as one atomic add per entry, all at once.

use burn::prelude::*;

/// `tensor.select(dim, index)`, computed as a `gather` so its backward is a parallel scatter.
/// `index` `[K]` picks along `dim`; the result has `K` there and `tensor`'s other sizes.
pub fn select_parallel<const D: usize>(
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

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// Values and gradients equal `select`'s, an index used twice and one never included.
    #[test]
    fn equals_select_in_value_and_gradient() {
        let device = Device::flex().autodiff();
        let x = Tensor::<3>::random([2, 5, 3], Distribution::Default, &device).require_grad();
        let index = Tensor::<1, Int>::from_ints([4, 0, 0, 2, 3, 4], &device);
        let w = Tensor::<3>::random([2, 6, 3], Distribution::Default, &device);
        let a = x.clone().select(1, index.clone());
        let b = select_parallel(x.clone(), 1, index);
        let max_diff = |p: Tensor<3>, q: Tensor<3>| (p - q).abs().max().into_scalar::<f32>();
        assert_eq!(max_diff(a.clone(), b.clone()), 0.0);
        let ga = x.grad(&(a * w.clone()).sum().backward()).unwrap();
        let gb = x.grad(&(b * w).sum().backward()).unwrap();
        let d = (ga.clone() - gb).abs().max().into_scalar::<f32>();
        assert!(d < 1e-6, "gradients differ by {d}");
        // Entry 1 is never picked: no gradient; entry 0, picked twice, gets two.
        assert_eq!(
            ga.clone()
                .slice([0..2, 1..2, 0..3])
                .abs()
                .sum()
                .into_scalar::<f32>(),
            0.0
        );
    }
}
