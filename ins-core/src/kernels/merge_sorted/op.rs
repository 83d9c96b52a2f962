//! The merge as a Burn op for the CubeCL backends (through Fusion, as an opaque operation)
//! under autodiff, which it leaves: merged samples are where to sample, not a value the loss
//! differentiates. Flex sorts on the host ([`crate::render::merge_rows`]).

use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Shape, backend_extension};
use burn::prelude::*;

use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The merge as a backend operation: `a [R, Ka]`, `b [R, Kb]`.
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait MergeOps: Backend {
    /// `[2, R, Ka + Kb]`: the merged rows, and each place's column in `[a, b]`.
    #[fusion(dtype = a, shape = Shape::new([2, a[0], a[1] + b[1]]))]
    fn merge_sorted(a: FloatTensor<Self>, b: FloatTensor<Self>) -> FloatTensor<Self>;
}

impl MergeOps for CubeBackend {
    fn merge_sorted(a: CubeTensor, b: CubeTensor) -> CubeTensor {
        super::cube::merge(a, b)
    }
}

impl<B: Backend + MergeOps, C: CheckpointStrategy> MergeOps for Autodiff<B, C> {
    fn merge_sorted(a: FloatTensor<Self>, b: FloatTensor<Self>) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::merge_sorted(
            a.into_primitive(),
            b.into_primitive(),
        ))
    }
}

/// `(merged [R, Ka + Kb], columns [R, Ka + Kb])` through the op, on devices where
/// [`crate::kernels::cube_device`] holds; `Ka, Kb ≥ 1`.
pub fn merge_op(a: Tensor<2>, b: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
    let ([r, ka], [_, kb]) = (a.dims(), b.dims());
    let both: Tensor<3> = Tensor::from_dispatch(<Dispatch as MergeOps>::merge_sorted(
        a.into_dispatch(),
        b.into_dispatch(),
    ));
    let [merged, columns] = [0, 1].map(|plane| {
        both.clone()
            .slice([plane..plane + 1, 0..r, 0..ka + kb])
            .reshape([r, ka + kb])
    });
    (merged, columns)
}
