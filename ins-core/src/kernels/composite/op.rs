//! Compositing as a Burn op with a hand-written backward, for the CubeCL backends (through
//! Fusion, as an opaque operation) under autodiff. Flex keeps the ordinary ops of
//! [`crate::render::volume::composite`], which run there as fast as a loop would.

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Shape, backend_extension};
use burn::prelude::*;

use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

use super::cube::{self, OUTPUTS};

/// Compositing's forward and backward as backend operations: `sigma [R, S]`, `rgb [R, S, 3]`,
/// `t [R, S]`, `delta [R, S]`, `background [3]`.
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait CompositeOps: Backend {
    /// `[R, 5]`: each ray's colour (background included), depth and opacity.
    #[fusion(dtype = sigma, shape = Shape::new([sigma[0], OUTPUTS]))]
    fn composite_forward(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        background: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// `[R, S]`: each sample's weight, without gradient (where to sample next).
    #[fusion(dtype = sigma, shape = Shape::new([sigma[0], sigma[1]]))]
    fn composite_weights(sigma: FloatTensor<Self>, delta: FloatTensor<Self>) -> FloatTensor<Self>;

    /// `(∂L/∂sigma, ∂L/∂rgb)` for the upstream gradient `grad [R, 5]` of the forward.
    #[fusion(meta = |sigma: &TensorSpec, rgb: &TensorSpec, _t: &TensorSpec, _delta: &TensorSpec, _background: &TensorSpec, _grad: &TensorSpec| (sigma.clone(), rgb.clone()))]
    fn composite_backward(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        background: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

impl CompositeOps for CubeBackend {
    fn composite_forward(
        sigma: CubeTensor,
        rgb: CubeTensor,
        t: CubeTensor,
        delta: CubeTensor,
        background: CubeTensor,
    ) -> CubeTensor {
        cube::forward(sigma, rgb, t, delta, background)
    }

    fn composite_weights(sigma: CubeTensor, delta: CubeTensor) -> CubeTensor {
        cube::weights(sigma, delta)
    }

    fn composite_backward(
        sigma: CubeTensor,
        rgb: CubeTensor,
        t: CubeTensor,
        delta: CubeTensor,
        background: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        cube::backward(sigma, rgb, t, delta, background, grad)
    }
}

#[derive(Debug)]
struct CompositeBackward;

/// The inputs the backward walks again.
type Inputs<B> = [FloatTensor<B>; 5];

impl<B: Backend + CompositeOps> Backward<B, 2> for CompositeBackward {
    type State = Inputs<B>;

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [sigma_node, rgb_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let [sigma, rgb, t, delta, background] = ops.state;
        let (grad_sigma, grad_rgb) = B::composite_backward(sigma, rgb, t, delta, background, grad);
        if let Some(node) = sigma_node {
            grads.register::<B>(node.id, grad_sigma);
        }
        if let Some(node) = rgb_node {
            grads.register::<B>(node.id, grad_rgb);
        }
    }
}

impl<B: Backend + CompositeOps, C: CheckpointStrategy> CompositeOps for Autodiff<B, C> {
    fn composite_forward(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        background: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let prep = CompositeBackward
            .prepare::<C>([sigma.node(), rgb.node()])
            .compute_bound()
            .stateful();
        let inputs: Inputs<B> = [
            sigma.into_primitive(),
            rgb.into_primitive(),
            t.into_primitive(),
            delta.into_primitive(),
            background.into_primitive(),
        ];
        let forward = |[s, c, t, d, b]: Inputs<B>| B::composite_forward(s, c, t, d, b);
        match prep {
            OpsKind::Tracked(prep) => {
                let out = forward(inputs.clone());
                prep.finish(inputs, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward(inputs)),
        }
    }

    fn composite_weights(sigma: FloatTensor<Self>, delta: FloatTensor<Self>) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::composite_weights(
            sigma.into_primitive(),
            delta.into_primitive(),
        ))
    }

    fn composite_backward(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        background: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_sigma, grad_rgb) = B::composite_backward(
            sigma.into_primitive(),
            rgb.into_primitive(),
            t.into_primitive(),
            delta.into_primitive(),
            background.into_primitive(),
            grad.into_primitive(),
        );
        (
            <Self as AutodiffBackend>::from_inner(grad_sigma),
            <Self as AutodiffBackend>::from_inner(grad_rgb),
        )
    }
}

/// `[R, 5]` through the op. Only for devices where [`crate::kernels::cube_device`] holds; gradients reach
/// `sigma` and `rgb` only.
pub fn composite_op(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    t: Tensor<2>,
    delta: Tensor<2>,
    background: Tensor<1>,
) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as CompositeOps>::composite_forward(
        sigma.into_dispatch(),
        rgb.into_dispatch(),
        t.into_dispatch(),
        delta.into_dispatch(),
        background.into_dispatch(),
    ))
}

/// `[R, S]`: the weights [`composite_op`] composites with, without gradient. Only for devices
/// where [`crate::kernels::cube_device`] holds.
pub fn weights_op(sigma: Tensor<2>, delta: Tensor<2>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as CompositeOps>::composite_weights(
        sigma.into_dispatch(),
        delta.into_dispatch(),
    ))
}
