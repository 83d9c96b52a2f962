//! The picks as a Burn op for the CubeCL backends (through Fusion, as an opaque operation)
//! under autodiff, which it leaves: picks are indices, not a value the loss differentiates.
//! Flex picks with ordinary ops ([`crate::render::flagged_picks`]).

use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Shape, backend_extension};
use burn::prelude::*;

use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The picks as a backend operation: `counts [N]`, `offsets [k]`.
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait RankedPickOps: Backend {
    /// `[2, k]`: each pick's entry and weight (see [`super::cube::pick`]).
    #[fusion(dtype = counts, shape = Shape::new([2, offsets[0]]))]
    fn ranked_picks(
        counts: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        steps: u32,
    ) -> FloatTensor<Self>;
}

impl RankedPickOps for CubeBackend {
    fn ranked_picks(counts: CubeTensor, offsets: CubeTensor, steps: u32) -> CubeTensor {
        super::cube::pick(counts, offsets, steps)
    }
}

impl<B: Backend + RankedPickOps, C: CheckpointStrategy> RankedPickOps for Autodiff<B, C> {
    fn ranked_picks(
        counts: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        steps: u32,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ranked_picks(
            counts.into_primitive(),
            offsets.into_primitive(),
            steps,
        ))
    }
}

/// `(entries [k], weights [k])` through the op, on devices where [`crate::kernels::cube_f32`]
/// holds: `counts [N]` the running count of flags (`1 ≤ N < 2²⁴`), `offsets [k]` below `steps`.
pub fn ranked_picks_op(
    counts: Tensor<1>,
    offsets: Tensor<1>,
    steps: u32,
) -> (Tensor<1, Int>, Tensor<1>) {
    let [k] = offsets.dims();
    let both: Tensor<2> = Tensor::from_dispatch(<Dispatch as RankedPickOps>::ranked_picks(
        counts.into_dispatch(),
        offsets.into_dispatch(),
        steps,
    ));
    let entries = both.clone().slice([0..1, 0..k]).reshape([k]).int();
    let weights = both.slice([1..2, 0..k]).reshape([k]);
    (entries, weights)
}
