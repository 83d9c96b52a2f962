//! Two sets of ray samples, each sorted along its rays, merged without leaving the device.
//! Burn's CubeCL backends (wgpu, CUDA) have no sort kernel: `sort` reads the tensor back, sorts
//! it on the host and uploads the result, a round trip that drains the GPU's queue twice a step
//! in IDR's volume and once in NeRF's hierarchical sampling. What those steps sort is always two
//! sorted sets (the coarse samples and the ones drawn from their weights), so there they are
//! merged, one kernel walking each ray's two sets once ([`crate::kernels::merge_sorted`]). On
//! Flex, whose sort runs in place on the host, the plain sort stays.

use burn::prelude::*;

use crate::kernels::cube_f32;
use crate::kernels::merge_sorted::op::merge_op;

/// `a [R, Ka]` and `b [R, Kb]`, each sorted ascending along its rows, as one sorted row each:
/// `[R, Ka + Kb]`, equal values from `a` first. No gradient flows through it off a CPU.
pub fn merge_rows(a: Tensor<2>, b: Tensor<2>) -> Tensor<2> {
    match on_device(&a, &b) {
        true => merge_op(a.detach(), b.detach()).0,
        false => Tensor::cat(vec![a, b], 1).sort(1),
    }
}

/// [`merge_rows`] with each merged value's column in `[a, b]` joined (`[R, Ka + Kb]`, for
/// gathering what goes with the values).
pub fn merge_rows_with_indices(a: Tensor<2>, b: Tensor<2>) -> (Tensor<2>, Tensor<2, Int>) {
    if on_device(&a, &b) {
        let (merged, columns) = merge_op(a.detach(), b.detach());
        return (merged, columns.int());
    }
    Tensor::cat(vec![a, b], 1).sort_with_indices(1)
}

/// Whether the merge kernel takes the rows: a CubeCL device, f32, both sets non-empty.
fn on_device(a: &Tensor<2>, b: &Tensor<2>) -> bool {
    a.dims()[1] > 0 && b.dims()[1] > 0 && cube_f32(&a.device(), &[a.dtype(), b.dtype()])
}
