//! The samplers as Burn ops for the CubeCL backends (through Fusion, as opaque operations)
//! under autodiff, which they leave: samples are where to evaluate, not values the loss
//! differentiates. Flex keeps the ordinary ops of [`crate::render::samplers`].

use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Shape, backend_extension};
use burn::prelude::*;

use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The samplers as backend operations; `seed` `None` puts each sample at its bin's centre.
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait SamplerOps: Backend {
    /// `[R, samples]`: stratified samples between `near [R]` and `far [R]`.
    #[fusion(dtype = near, shape = Shape::new([near[0], *samples]))]
    fn stratified_samples(
        near: FloatTensor<Self>,
        far: FloatTensor<Self>,
        samples: usize,
        seed: Option<u64>,
    ) -> FloatTensor<Self>;

    /// `[R, draws]`: each ray's new distances from `t [R, S]` and `weights [R, S]`, in
    /// increasing order.
    #[fusion(dtype = t, shape = Shape::new([t[0], *draws]))]
    fn draw_from_cdf(
        t: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        draws: usize,
        seed: Option<u64>,
    ) -> FloatTensor<Self>;
}

impl SamplerOps for CubeBackend {
    fn stratified_samples(
        near: CubeTensor,
        far: CubeTensor,
        samples: usize,
        seed: Option<u64>,
    ) -> CubeTensor {
        super::cube::stratified(near, far, samples, seed)
    }

    fn draw_from_cdf(
        t: CubeTensor,
        weights: CubeTensor,
        draws: usize,
        seed: Option<u64>,
    ) -> CubeTensor {
        super::cube::draw(t, weights, draws, seed)
    }
}

impl<B: Backend + SamplerOps, C: CheckpointStrategy> SamplerOps for Autodiff<B, C> {
    fn stratified_samples(
        near: FloatTensor<Self>,
        far: FloatTensor<Self>,
        samples: usize,
        seed: Option<u64>,
    ) -> FloatTensor<Self> {
        let (near, far) = (near.into_primitive(), far.into_primitive());
        <Self as AutodiffBackend>::from_inner(B::stratified_samples(near, far, samples, seed))
    }

    fn draw_from_cdf(
        t: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        draws: usize,
        seed: Option<u64>,
    ) -> FloatTensor<Self> {
        let (t, weights) = (t.into_primitive(), weights.into_primitive());
        <Self as AutodiffBackend>::from_inner(B::draw_from_cdf(t, weights, draws, seed))
    }
}

/// `[R, samples]` stratified samples through the op, on devices where
/// [`crate::kernels::cube_device`] holds.
pub fn stratified_op(
    near: Tensor<1>,
    far: Tensor<1>,
    samples: usize,
    seed: Option<u64>,
) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SamplerOps>::stratified_samples(
        near.into_dispatch(),
        far.into_dispatch(),
        samples,
        seed,
    ))
}

/// `[R, draws]` through the op, on devices where [`crate::kernels::cube_device`] holds.
pub fn draw_op(t: Tensor<2>, weights: Tensor<2>, draws: usize, seed: Option<u64>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SamplerOps>::draw_from_cdf(
        t.into_dispatch(),
        weights.into_dispatch(),
        draws,
        seed,
    ))
}
