//! The inverse-CDF draws as a Burn op for the CubeCL backends (through Fusion, as an opaque
//! operation) under autodiff, which it leaves: the draws are where to sample, not a value
//! the loss differentiates. Flex keeps the ordinary ops of
//! [`crate::render::samplers::draw_from_weights`].

use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Shape, backend_extension};
use burn::prelude::*;

use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The draws as a backend operation: `t [R, S]`, `weights [R, S]`, `jitter [R, n]`.
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait InverseCdfOps: Backend {
    /// `[R, n]`: each ray's new distances, in increasing order.
    #[fusion(dtype = t, shape = Shape::new([t[0], jitter[1]]))]
    fn draw_from_cdf(
        t: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        jitter: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

impl InverseCdfOps for CubeBackend {
    fn draw_from_cdf(t: CubeTensor, weights: CubeTensor, jitter: CubeTensor) -> CubeTensor {
        super::cube::draw(t, weights, jitter)
    }
}

impl<B: Backend + InverseCdfOps, C: CheckpointStrategy> InverseCdfOps for Autodiff<B, C> {
    fn draw_from_cdf(
        t: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        jitter: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::draw_from_cdf(
            t.into_primitive(),
            weights.into_primitive(),
            jitter.into_primitive(),
        ))
    }
}

/// `[R, n]` through the op, on devices where [`crate::kernels::cube_device`] holds.
pub fn draw_op(t: Tensor<2>, weights: Tensor<2>, jitter: Tensor<2>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as InverseCdfOps>::draw_from_cdf(
        t.into_dispatch(),
        weights.into_dispatch(),
        jitter.into_dispatch(),
    ))
}
