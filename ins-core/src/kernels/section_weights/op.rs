//! NeuS's section weights as a Burn op with a hand-written backward, for the CubeCL backends
//! (through Fusion, as an opaque operation) under autodiff. Flex keeps the ordinary ops of
//! [`crate::render::sdf_volume`].

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

/// The weights and their backward as backend operations: `ends [R, S + 1]` (the SDF at the
/// sections' ends), `live [R]`, `sharpness [1]`.
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait SectionWeightOps: Backend {
    /// `[R, S]`: each section's compositing weight.
    #[fusion(dtype = ends, shape = Shape::new([ends[0], ends[1] - 1]))]
    fn section_weights(
        ends: FloatTensor<Self>,
        live: FloatTensor<Self>,
        sharpness: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// `(∂L/∂ends, ∂L/∂sharpness per ray [R])` for the upstream gradient `grad [R, S]` of
    /// the forward, whose output `weights [R, S]` was.
    #[fusion(meta = |ends: &TensorSpec, live: &TensorSpec, _sharpness: &TensorSpec, _weights: &TensorSpec, _grad: &TensorSpec| (ends.clone(), live.clone()))]
    fn section_weights_backward(
        ends: FloatTensor<Self>,
        live: FloatTensor<Self>,
        sharpness: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

impl SectionWeightOps for CubeBackend {
    fn section_weights(ends: CubeTensor, live: CubeTensor, sharpness: CubeTensor) -> CubeTensor {
        super::cube::forward(ends, live, sharpness)
    }

    fn section_weights_backward(
        ends: CubeTensor,
        live: CubeTensor,
        sharpness: CubeTensor,
        weights: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        super::cube::backward(ends, live, sharpness, weights, grad)
    }
}

#[derive(Debug)]
struct SectionWeightsBackward;

/// The inputs the backward walks again.
type Inputs<B> = [FloatTensor<B>; 3];

/// The inputs and the forward's weights.
type State<B> = [FloatTensor<B>; 4];

impl<B: Backend + SectionWeightOps> Backward<B, 2> for SectionWeightsBackward {
    type State = State<B>;

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [ends_node, sharpness_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let [ends, live, sharpness, weights] = ops.state;
        let (grad_ends, per_ray) =
            B::section_weights_backward(ends, live, sharpness, weights, grad);
        if let Some(node) = ends_node {
            grads.register::<B>(node.id, grad_ends);
        }
        if let Some(node) = sharpness_node {
            grads.register::<B>(node.id, B::float_sum(per_ray));
        }
    }
}

impl<B: Backend + SectionWeightOps, C: CheckpointStrategy> SectionWeightOps for Autodiff<B, C> {
    fn section_weights(
        ends: FloatTensor<Self>,
        live: FloatTensor<Self>,
        sharpness: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let prep = SectionWeightsBackward
            .prepare::<C>([ends.node(), sharpness.node()])
            .compute_bound()
            .stateful();
        let inputs: Inputs<B> = [
            ends.into_primitive(),
            live.into_primitive(),
            sharpness.into_primitive(),
        ];
        let forward = |[f, l, s]: Inputs<B>| B::section_weights(f, l, s);
        match prep {
            OpsKind::Tracked(prep) => {
                let out = forward(inputs.clone());
                let [f, l, s] = inputs;
                prep.finish([f, l, s, out.clone()], out)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward(inputs)),
        }
    }

    fn section_weights_backward(
        ends: FloatTensor<Self>,
        live: FloatTensor<Self>,
        sharpness: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_ends, per_ray) = B::section_weights_backward(
            ends.into_primitive(),
            live.into_primitive(),
            sharpness.into_primitive(),
            weights.into_primitive(),
            grad.into_primitive(),
        );
        (
            <Self as AutodiffBackend>::from_inner(grad_ends),
            <Self as AutodiffBackend>::from_inner(per_ray),
        )
    }
}

/// `[R, S]` through the op, on devices where [`crate::kernels::cube_device`] holds;
/// gradients reach `ends` and `sharpness`.
pub fn section_weights_op(ends: Tensor<2>, live: Tensor<1>, sharpness: Tensor<1>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SectionWeightOps>::section_weights(
        ends.into_dispatch(),
        live.into_dispatch(),
        sharpness.into_dispatch(),
    ))
}
