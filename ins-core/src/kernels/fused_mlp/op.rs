//! The fused chain as a Burn op with a hand-written backward, for the CubeCL backends (through
//! Fusion, as an opaque operation) and under autodiff.

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

use super::{MAX_LAYERS, MlpShape, param_shapes};

/// The chain's forward and its two backward passes as backend operations: `x [N, I]`, each
/// layer's weights `[I, O]` and bias `[O]` (a two-layer chain's third layer is never read).
#[backend_extension(Cube, Fusion, Autodiff)]
pub trait FusedMlpOps: Backend {
    /// `(y [N, O_last], hidden [N, ΣO of the layers before the last])`: the output and the
    /// hidden layers' outputs (after their ReLUs), which the backward reads.
    #[fusion(meta = |x: &TensorSpec, _w0: &TensorSpec, _b0: &TensorSpec, _w1: &TensorSpec, _b1: &TensorSpec, _w2: &TensorSpec, _b2: &TensorSpec, shape: &MlpShape| (
        TensorSpec::new(Shape::new([x.shape[0], shape.out_width()]), x.dtype),
        TensorSpec::new(Shape::new([x.shape[0], shape.hidden_width()]), x.dtype),
    ))]
    #[allow(clippy::too_many_arguments)]
    fn fused_mlp_forward(
        x: FloatTensor<Self>,
        w0: FloatTensor<Self>,
        b0: FloatTensor<Self>,
        w1: FloatTensor<Self>,
        b1: FloatTensor<Self>,
        w2: FloatTensor<Self>,
        b2: FloatTensor<Self>,
        shape: MlpShape,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// `(∂L/∂x [N, I], ∂L/∂(each layer's pre-activation) [N, ΣO])` for the upstream gradient
    /// `grad [N, O_last]`, from the forward's `hidden` and `y`.
    #[fusion(meta = |hidden: &TensorSpec, _y: &TensorSpec, _w0: &TensorSpec, _w1: &TensorSpec, _w2: &TensorSpec, _grad: &TensorSpec, shape: &MlpShape| (
        TensorSpec::new(Shape::new([hidden.shape[0], shape.input(0)]), hidden.dtype),
        TensorSpec::new(Shape::new([hidden.shape[0], shape.pre_width()]), hidden.dtype),
    ))]
    fn fused_mlp_backward(
        hidden: FloatTensor<Self>,
        y: FloatTensor<Self>,
        w0: FloatTensor<Self>,
        w1: FloatTensor<Self>,
        w2: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        shape: MlpShape,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// `(∂L/∂w0, ∂L/∂b0, ∂L/∂w1, ∂L/∂b1, ∂L/∂w2, ∂L/∂b2)`: every weight's and bias's gradient,
    /// summed over the rows, from the input, the hidden outputs and the pre-activation
    /// gradients (a chain of two: the last two `[1, 1]` and `[1]`, never written).
    #[fusion(meta = |x: &TensorSpec, _hidden: &TensorSpec, _grad_pre: &TensorSpec, shape: &MlpShape| {
        let [w0, b0, w1, b1, w2, b2] = param_shapes(*shape).map(|dims| TensorSpec::new(Shape::from(dims), x.dtype));
        (w0, b0, w1, b1, w2, b2)
    })]
    #[allow(clippy::type_complexity)]
    fn fused_mlp_param_grads(
        x: FloatTensor<Self>,
        hidden: FloatTensor<Self>,
        grad_pre: FloatTensor<Self>,
        shape: MlpShape,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    );
}

impl FusedMlpOps for CubeBackend {
    fn fused_mlp_forward(
        x: CubeTensor,
        w0: CubeTensor,
        b0: CubeTensor,
        w1: CubeTensor,
        b1: CubeTensor,
        w2: CubeTensor,
        b2: CubeTensor,
        shape: MlpShape,
    ) -> (CubeTensor, CubeTensor) {
        super::cube::forward(x, [w0, b0, w1, b1, w2, b2], shape)
    }

    fn fused_mlp_backward(
        hidden: CubeTensor,
        y: CubeTensor,
        w0: CubeTensor,
        w1: CubeTensor,
        w2: CubeTensor,
        grad: CubeTensor,
        shape: MlpShape,
    ) -> (CubeTensor, CubeTensor) {
        super::cube::backward(hidden, y, [w0, w1, w2], grad, shape)
    }

    fn fused_mlp_param_grads(
        x: CubeTensor,
        hidden: CubeTensor,
        grad_pre: CubeTensor,
        shape: MlpShape,
    ) -> ParamGrads<CubeBackend> {
        let [w0, b0, w1, b1, w2, b2] = super::cube::param_grads(x, hidden, grad_pre, shape);
        (w0, b0, w1, b1, w2, b2)
    }
}

/// [`FusedMlpOps::fused_mlp_param_grads`]' six gradients (the trait spells the tuple out: its
/// macro reads the outputs from it).
type ParamGrads<B> = (
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
);

#[derive(Debug)]
struct FusedMlpBackward {
    shape: MlpShape,
}

/// What the backward reads: `[x, hidden, y, w0, w1, w2]`.
type State<B> = [FloatTensor<B>; 6];

/// The op's inputs: `x`, then each layer's weights and bias.
const INPUTS: usize = 1 + 2 * MAX_LAYERS;

impl<B: Backend + FusedMlpOps> Backward<B, INPUTS> for FusedMlpBackward {
    type State = State<B>;

    fn backward(self, ops: Ops<Self::State, INPUTS>, grads: &mut Gradients, _: &mut Checkpointer) {
        let shape = self.shape;
        let grad = grads.consume::<B>(&ops.node);
        let [x_node, params @ ..] = ops.parents;
        let [x, hidden, y, w0, w1, w2] = ops.state;
        let (grad_x, grad_pre) = B::fused_mlp_backward(hidden.clone(), y, w0, w1, w2, grad, shape);
        if let Some(node) = x_node {
            grads.register::<B>(node.id, grad_x);
        }
        if params.iter().all(Option::is_none) {
            return;
        }
        let (w0, b0, w1, b1, w2, b2) = B::fused_mlp_param_grads(x, hidden, grad_pre, shape);
        let layers = shape.layers();
        for (k, (node, grad)) in params.into_iter().zip([w0, b0, w1, b1, w2, b2]).enumerate() {
            if let Some(node) = node.filter(|_| k / 2 < layers) {
                grads.register::<B>(node.id, grad);
            }
        }
    }
}

impl<B: Backend + FusedMlpOps, C: CheckpointStrategy> FusedMlpOps for Autodiff<B, C> {
    fn fused_mlp_forward(
        x: FloatTensor<Self>,
        w0: FloatTensor<Self>,
        b0: FloatTensor<Self>,
        w1: FloatTensor<Self>,
        b1: FloatTensor<Self>,
        w2: FloatTensor<Self>,
        b2: FloatTensor<Self>,
        shape: MlpShape,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let prep = FusedMlpBackward { shape }
            .prepare::<C>([
                x.node(),
                w0.node(),
                b0.node(),
                w1.node(),
                b1.node(),
                w2.node(),
                b2.node(),
            ])
            .compute_bound()
            .stateful();
        let [x, w0, b0, w1, b1, w2, b2] = [x, w0, b0, w1, b1, w2, b2].map(|t| t.into_primitive());
        let weights = [w0.clone(), w1.clone(), w2.clone()];
        let (y, hidden) = B::fused_mlp_forward(x.clone(), w0, b0, w1, b1, w2, b2, shape);
        let kept = <Self as AutodiffBackend>::from_inner(hidden.clone());
        match prep {
            OpsKind::Tracked(prep) => {
                let [w0, w1, w2] = weights;
                (prep.finish([x, hidden, y.clone(), w0, w1, w2], y), kept)
            }
            OpsKind::UnTracked(prep) => (prep.finish(y), kept),
        }
    }

    fn fused_mlp_backward(
        hidden: FloatTensor<Self>,
        y: FloatTensor<Self>,
        w0: FloatTensor<Self>,
        w1: FloatTensor<Self>,
        w2: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        shape: MlpShape,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let [hidden, y, w0, w1, w2, grad] =
            [hidden, y, w0, w1, w2, grad].map(|t| t.into_primitive());
        let (grad_x, grad_pre) = B::fused_mlp_backward(hidden, y, w0, w1, w2, grad, shape);
        (
            <Self as AutodiffBackend>::from_inner(grad_x),
            <Self as AutodiffBackend>::from_inner(grad_pre),
        )
    }

    fn fused_mlp_param_grads(
        x: FloatTensor<Self>,
        hidden: FloatTensor<Self>,
        grad_pre: FloatTensor<Self>,
        shape: MlpShape,
    ) -> ParamGrads<Self> {
        let [x, hidden, grad_pre] = [x, hidden, grad_pre].map(|t| t.into_primitive());
        let (w0, b0, w1, b1, w2, b2) = B::fused_mlp_param_grads(x, hidden, grad_pre, shape);
        let [w0, b0, w1, b1, w2, b2] =
            [w0, b0, w1, b1, w2, b2].map(<Self as AutodiffBackend>::from_inner);
        (w0, b0, w1, b1, w2, b2)
    }
}

/// `x [N, I]` through two or three `layers` (weights `[I, O]`, biases `[O]`, a ReLU after or
/// not) as one op; gradients reach `x` and every weight and bias that asks for one.
///
/// # Panics
/// Unless there are two or three layers whose widths chain up.
pub fn fused_mlp(x: Tensor<2>, layers: &[(Tensor<2>, Tensor<1>, bool)]) -> Tensor<2> {
    assert!(
        (2..=MAX_LAYERS).contains(&layers.len()),
        "a fused chain of {} layers",
        layers.len()
    );
    let mut shape = MlpShape {
        widths: [0; MAX_LAYERS + 1],
        relu: [false; MAX_LAYERS],
    };
    shape.widths[0] = x.dims()[1];
    for (l, (w, b, relu)) in layers.iter().enumerate() {
        let [i, o] = w.dims();
        assert!(
            i == shape.widths[l] && b.dims()[0] == o,
            "layer {l}: {:?} weights, {:?} bias after {} columns",
            w.dims(),
            b.dims(),
            shape.widths[l]
        );
        shape.widths[l + 1] = o;
        shape.relu[l] = *relu;
    }
    // A two-layer chain's third is a stand-in the kernels never read (detached: no gradient).
    let (last_w, last_b) = (&layers[layers.len() - 1].0, &layers[layers.len() - 1].1);
    let param = |l: usize| match layers.get(l) {
        Some((w, b, _)) => (w.clone(), b.clone()),
        None => (last_w.clone().detach(), last_b.clone().detach()),
    };
    let ((w0, b0), (w1, b1), (w2, b2)) = (param(0), param(1), param(2));
    let (y, _) = <Dispatch as FusedMlpOps>::fused_mlp_forward(
        x.into_dispatch(),
        w0.into_dispatch(),
        b0.into_dispatch(),
        w1.into_dispatch(),
        b1.into_dispatch(),
        w2.into_dispatch(),
        b2.into_dispatch(),
        shape,
    );
    Tensor::from_dispatch(y)
}
