//! The convolution as a Burn op on Flex, with a hand-written backward under autodiff: the input
//! gradient by the same im2col + GEMM routine as the forward, the weight and bias gradients only
//! when those tensors are tracked (a frozen VGG never pays for them).

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, DispatchDevice, Flex, TensorData,
    TensorMetadata, backend_extension,
};
use burn::prelude::*;

use crate::conv;
use crate::engine::Engine;
use crate::geometry::ConvGeometry;
use crate::kernel_cache::{self, Role};
use crate::kernel_matrix::KernelMatrix;

/// Stride, padding and engine of one convolution (the rest comes from the tensors' shapes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ConvParams {
    /// Stride along height and width.
    pub stride: [usize; 2],
    /// Zero padding on each side along height and width.
    pub padding: [usize; 2],
    /// The GEMM engine of the forward and the input gradient.
    pub engine: Engine,
    /// A ReLU fused after the convolution (and its mask fused into the input gradient).
    pub relu: bool,
    /// The kernel is constant (a frozen network's): keep its GEMM layout between calls (see
    /// [`crate::kernel_cache`]). Autodiff ignores it where the kernel is tracked.
    pub reuse_kernel: bool,
}

impl ConvParams {
    /// The forward geometry, from the output gradient, the weight and the input's size.
    fn backward_geometry(
        &self,
        grad_out: &impl TensorMetadata,
        weight: &impl TensorMetadata,
        input_hw: [usize; 2],
    ) -> ConvGeometry {
        let (gs, ws) = (grad_out.shape(), weight.shape());
        ConvGeometry {
            batch: gs[0],
            c_in: ws[1],
            c_out: ws[0],
            input: input_hw,
            kernel: [ws[2], ws[3]],
            stride: self.stride,
            padding: self.padding,
        }
    }

    fn geometry(&self, x: &impl TensorMetadata, weight: &impl TensorMetadata) -> ConvGeometry {
        let (xs, ws) = (x.shape(), weight.shape());
        assert_eq!(
            xs[1], ws[1],
            "input channels {} but the kernel expects {}",
            xs[1], ws[1]
        );
        let g = ConvGeometry {
            batch: xs[0],
            c_in: xs[1],
            c_out: ws[0],
            input: [xs[2], xs[3]],
            kernel: [ws[2], ws[3]],
            stride: self.stride,
            padding: self.padding,
        };
        assert!(
            g.output().is_some(),
            "the kernel does not fit the padded input: {g:?}"
        );
        g
    }
}

/// The convolution's forward and gradients as backend operations.
#[backend_extension(Flex, Autodiff)]
pub trait ConvOps: Backend {
    /// `x [B, Ci, H, W]`, `weight [Co, Ci, kh, kw]`, `bias [Co]` → `[B, Co, Ho, Wo]`.
    fn ins_conv2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        params: ConvParams,
    ) -> FloatTensor<Self>;

    /// `∂L/∂x` (`[B, Ci, H, W]`, of `input_shape`) for `grad_out [B, Co, Ho, Wo]`.
    fn ins_conv2d_input_grad(
        grad_out: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        input_hw: [usize; 2],
        params: ConvParams,
    ) -> FloatTensor<Self>;

    /// `∂L/∂x` through the fused ReLU: `grad_out` counts where `relu_out` (the op's output) is
    /// positive.
    fn ins_conv2d_relu_input_grad(
        grad_out: FloatTensor<Self>,
        relu_out: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        input_hw: [usize; 2],
        params: ConvParams,
    ) -> FloatTensor<Self>;

    /// `grad_out` where `relu_out` is positive, zero elsewhere (the fused ReLU's backward).
    fn ins_relu_gate(grad_out: FloatTensor<Self>, relu_out: FloatTensor<Self>)
    -> FloatTensor<Self>;

    /// `∂L/∂weight` (`[Co, Ci, kh, kw]`) for `grad_out [B, Co, Ho, Wo]`.
    fn ins_conv2d_weight_grad(
        x: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        kernel: [usize; 2],
        params: ConvParams,
    ) -> FloatTensor<Self>;
}

/// `t`'s values, contiguous, to `f` (the crate's ops, the convolution and the max pool, run in f32).
pub(crate) fn values<R>(t: &FlexTensor, f: impl FnOnce(&[f32]) -> R) -> R {
    assert_eq!(t.dtype(), DType::F32, "ins-conv's ops run in f32");
    let t = t.to_contiguous();
    f(t.as_slice::<f32>().expect("contiguous f32"))
}

/// The kernel matrix of `weight` for `role`: kept between calls when `params` allow it.
fn kernel_matrix(
    weight: &FlexTensor,
    g: &ConvGeometry,
    role: Role,
    params: ConvParams,
) -> std::sync::Arc<KernelMatrix> {
    let build = || {
        values(weight, |w| match role {
            Role::Forward => KernelMatrix::forward(w, g, params.engine),
            Role::InputGrad => KernelMatrix::input_grad(w, g, params.engine),
        })
    };
    if params.reuse_kernel {
        kernel_cache::kernel_matrix(weight, role, params.engine, build)
    } else {
        std::sync::Arc::new(build())
    }
}

pub(crate) fn tensor(values: Vec<f32>, shape: [usize; 4]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

impl ConvOps for Flex {
    fn ins_conv2d(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        params: ConvParams,
    ) -> FlexTensor {
        let g = params.geometry(&x, &weight);
        // The f32 forward reads the weights as they are: nothing to build or keep.
        let kernel = (params.engine != Engine::F32)
            .then(|| kernel_matrix(&weight, &g, Role::Forward, params));
        let y = values(&x, |x| {
            values(&bias, |b| match &kernel {
                Some(kernel) => conv::forward_with(x, kernel, Some(b), &g, params.relu),
                None => values(&weight, |w| {
                    conv::forward(x, w, Some(b), &g, params.relu, Engine::F32)
                }),
            })
        });
        let [ho, wo] = g.out_hw();
        tensor(y, [g.batch, g.c_out, ho, wo])
    }

    fn ins_conv2d_input_grad(
        grad_out: FlexTensor,
        weight: FlexTensor,
        input_hw: [usize; 2],
        params: ConvParams,
    ) -> FlexTensor {
        let g = params.backward_geometry(&grad_out, &weight, input_hw);
        let kernel = kernel_matrix(&weight, &g, Role::InputGrad, params);
        let dx = values(&grad_out, |go| conv::input_grad_with(go, None, &kernel, &g));
        tensor(dx, [g.batch, g.c_in, input_hw[0], input_hw[1]])
    }

    fn ins_conv2d_relu_input_grad(
        grad_out: FlexTensor,
        relu_out: FlexTensor,
        weight: FlexTensor,
        input_hw: [usize; 2],
        params: ConvParams,
    ) -> FlexTensor {
        let g = params.backward_geometry(&grad_out, &weight, input_hw);
        let kernel = kernel_matrix(&weight, &g, Role::InputGrad, params);
        let dx = values(&grad_out, |go| {
            values(&relu_out, |y| {
                conv::input_grad_with(go, Some(y), &kernel, &g)
            })
        });
        tensor(dx, [g.batch, g.c_in, input_hw[0], input_hw[1]])
    }

    fn ins_relu_gate(grad_out: FlexTensor, relu_out: FlexTensor) -> FlexTensor {
        let shape = grad_out.shape();
        let gated = values(&grad_out, |go| {
            values(&relu_out, |y| conv::relu_gate(go, y))
        });
        FlexTensor::from_data(TensorData::new(gated, shape))
    }

    fn ins_conv2d_weight_grad(
        x: FlexTensor,
        grad_out: FlexTensor,
        kernel: [usize; 2],
        params: ConvParams,
    ) -> FlexTensor {
        let (xs, gs) = (x.shape(), grad_out.shape());
        let g = ConvGeometry {
            batch: xs[0],
            c_in: xs[1],
            c_out: gs[1],
            input: [xs[2], xs[3]],
            kernel,
            stride: params.stride,
            padding: params.padding,
        };
        let dw = values(&x, |x| values(&grad_out, |go| conv::weight_grad(x, go, &g)));
        tensor(dw, [g.c_out, g.c_in, kernel[0], kernel[1]])
    }
}

#[derive(Debug)]
struct ConvBackward;

impl<B: Backend + ConvOps> Backward<B, 3> for ConvBackward {
    /// The input (for the weight gradient), the weight (for the input gradient), the output
    /// when a ReLU is fused (its mask), the params.
    type State = (
        FloatTensor<B>,
        FloatTensor<B>,
        Option<FloatTensor<B>>,
        ConvParams,
    );

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node, weight_node, bias_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (x, weight, relu_out, params) = ops.state;
        let ws = weight.shape();
        let xs = x.shape();
        if weight_node.is_some() || bias_node.is_some() {
            let gated = match &relu_out {
                Some(y) => B::ins_relu_gate(grad.clone(), y.clone()),
                None => grad.clone(),
            };
            if let Some(node) = bias_node {
                // Σ over batch, height and width.
                let g =
                    B::float_sum_dim(B::float_sum_dim(B::float_sum_dim(gated.clone(), 0), 2), 3);
                grads.register::<B>(node.id, B::float_reshape(g, [ws[0]].into()));
            }
            if let Some(node) = weight_node {
                let g = B::ins_conv2d_weight_grad(x, gated, [ws[2], ws[3]], params);
                grads.register::<B>(node.id, g);
            }
        }
        if let Some(node) = x_node {
            let hw = [xs[2], xs[3]];
            let g = match relu_out {
                Some(y) => B::ins_conv2d_relu_input_grad(grad, y, weight, hw, params),
                None => B::ins_conv2d_input_grad(grad, weight, hw, params),
            };
            grads.register::<B>(node.id, g);
        }
    }
}

impl<B: Backend + ConvOps, C: CheckpointStrategy> ConvOps for Autodiff<B, C> {
    fn ins_conv2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        params: ConvParams,
    ) -> FloatTensor<Self> {
        // A kernel that learns changes every step: keeping its matrices would only pin memory.
        let params = ConvParams {
            reuse_kernel: params.reuse_kernel && !weight.is_tracked(),
            ..params
        };
        match ConvBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (x, w) = (x.into_primitive(), weight.into_primitive());
                let y = B::ins_conv2d(x.clone(), w.clone(), bias.into_primitive(), params);
                let relu_out = params.relu.then(|| y.clone());
                prep.finish((x, w, relu_out, params), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::ins_conv2d(
                x.into_primitive(),
                weight.into_primitive(),
                bias.into_primitive(),
                params,
            )),
        }
    }

    fn ins_conv2d_input_grad(
        grad_out: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        input_hw: [usize; 2],
        params: ConvParams,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ins_conv2d_input_grad(
            grad_out.into_primitive(),
            weight.into_primitive(),
            input_hw,
            params,
        ))
    }

    fn ins_conv2d_relu_input_grad(
        grad_out: FloatTensor<Self>,
        relu_out: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        input_hw: [usize; 2],
        params: ConvParams,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ins_conv2d_relu_input_grad(
            grad_out.into_primitive(),
            relu_out.into_primitive(),
            weight.into_primitive(),
            input_hw,
            params,
        ))
    }

    fn ins_relu_gate(
        grad_out: FloatTensor<Self>,
        relu_out: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ins_relu_gate(
            grad_out.into_primitive(),
            relu_out.into_primitive(),
        ))
    }

    fn ins_conv2d_weight_grad(
        x: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        kernel: [usize; 2],
        params: ConvParams,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ins_conv2d_weight_grad(
            x.into_primitive(),
            grad_out.into_primitive(),
            kernel,
            params,
        ))
    }
}

/// Whether the op runs on this device (Flex, with or without autodiff).
pub fn kernel_device(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Flex(_)
    )
}

/// Whether `device` is a GPU (CubeCL's wgpu runtime) whose adapter computes in f16.
pub fn half_device(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Cube(_)
    ) && device.supports_dtype(DType::F16)
}

/// `x [B, Ci, H, W]` convolved with `weight [Co, Ci, kh, kw]` (+ `bias [Co]`), through the op.
/// Only for devices where [`kernel_device`] holds.
pub fn conv2d(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    params: ConvParams,
) -> Tensor<4> {
    let bias = bias.unwrap_or_else(|| Tensor::zeros([weight.dims()[0]], &weight.device()));
    Tensor::from_dispatch(<Dispatch as ConvOps>::ins_conv2d(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        params,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;
    use burn::tensor::module::conv2d as burn_conv2d;
    use burn::tensor::ops::ConvOptions;

    fn close(a: Tensor<4>, b: Tensor<4>, tol: f32, what: &str) {
        let scale = b.clone().abs().max().into_scalar::<f32>().max(1e-6);
        let err = (a - b).abs().max().into_scalar::<f32>() / scale;
        assert!(err < tol, "{what}: relative error {err}");
    }

    /// Against Burn's own conv2d under autodiff: values and the gradients of the input, the
    /// weight and the bias, on odd shapes; every engine this CPU runs.
    #[test]
    fn matches_burn_conv2d_in_value_and_all_gradients() {
        let d = Device::flex().autodiff();
        d.seed(3);
        let cases = [
            ([2, 7, 9, 6], [13, 7, 3, 3], [1, 1], [1, 1]),
            ([1, 3, 16, 16], [64, 3, 3, 3], [1, 1], [1, 1]),
            ([1, 5, 6, 11], [4, 5, 1, 1], [1, 1], [0, 0]),
            ([2, 6, 10, 9], [17, 6, 3, 2], [2, 3], [1, 0]),
        ];
        let tol = |e: Engine| if e == Engine::F32 { 1e-5 } else { 2e-2 };
        let engines: Vec<_> = Engine::available()
            .into_iter()
            .map(|e| (e, tol(e)))
            .collect();
        for (engine, tol) in engines {
            for ((xs, ws, stride, padding), relu) in
                cases.iter().flat_map(|c| [(*c, false), (*c, true)])
            {
                let x = Tensor::<4>::random(xs, Distribution::Default, &d).require_grad();
                let w = Tensor::<4>::random(ws, Distribution::Normal(0.0, 0.3), &d).require_grad();
                let b = Tensor::<1>::random([ws[0]], Distribution::Default, &d).require_grad();
                // Tracked weights: autodiff must ignore `reuse_kernel`.
                let params = ConvParams {
                    stride,
                    padding,
                    engine,
                    relu,
                    reuse_kernel: true,
                };
                let y = conv2d(x.clone(), w.clone(), Some(b.clone()), params);
                let opts = ConvOptions::new(stride, padding, [1, 1], 1);
                let conv_ref = burn_conv2d(x.clone(), w.clone(), Some(b.clone()), opts);
                let what = format!("{engine:?} {xs:?} {ws:?} relu {relu}");
                // The ReLU's gradient is taken where the op's own output is positive: in bf16 an
                // output near zero may have the other sign than in f32.
                let y_ref = match relu {
                    true => {
                        let value = burn::tensor::activation::relu(conv_ref.clone());
                        close(y.clone(), value, tol, &format!("y {what}"));
                        conv_ref * y.clone().detach().greater_elem(0.0).float()
                    }
                    false => {
                        close(y.clone(), conv_ref.clone(), tol, &format!("y {what}"));
                        conv_ref
                    }
                };
                // A loss that weighs every output differently.
                let probe = Tensor::<4>::random(y.dims(), Distribution::Default, &d);
                let g = (y * probe.clone()).sum().backward();
                let g_ref = (y_ref * probe).sum().backward();
                close(
                    x.grad(&g).unwrap(),
                    x.grad(&g_ref).unwrap(),
                    tol,
                    &format!("dx {what}"),
                );
                // The weight gradient is f32 in both engines.
                close(
                    w.grad(&g).unwrap(),
                    w.grad(&g_ref).unwrap(),
                    1e-5,
                    &format!("dw {what}"),
                );
                let (db, db_ref) = (b.grad(&g).unwrap(), b.grad(&g_ref).unwrap());
                let err = (db - db_ref).abs().max().into_scalar::<f32>();
                assert!(err < 1e-3, "db {what}: {err}");
            }
        }
    }

    #[test]
    fn untracked_weights_get_no_gradient() {
        let d = Device::flex().autodiff();
        let x = Tensor::<4>::random([1, 4, 8, 8], Distribution::Default, &d).require_grad();
        let w = Tensor::<4>::random([6, 4, 3, 3], Distribution::Default, &d);
        let params = ConvParams {
            stride: [1, 1],
            padding: [1, 1],
            engine: Engine::F32,
            relu: true,
            reuse_kernel: false,
        };
        let g = conv2d(x.clone(), w.clone(), None, params).sum().backward();
        assert!(x.grad(&g).is_some());
        assert!(w.grad(&g).is_none());
    }

    /// A frozen kernel's matrices are built once, and a kernel changed afterwards, even by an
    /// op that could write in place, is never served its old matrices.
    #[test]
    fn frozen_kernels_are_built_once_and_never_stale() {
        let d = Device::flex().autodiff();
        d.seed(5);
        // The BF16 forward keeps a matrix too; the f32 one reads the weights as they are.
        let engines = Engine::available().into_iter().map(|e| match e {
            Engine::F32 => (e, 1e-5, 1),
            _ => (e, 2e-2, 2),
        });
        for (engine, tol, per_kernel) in engines {
            let params = ConvParams {
                stride: [1, 1],
                padding: [1, 1],
                engine,
                relu: false,
                reuse_kernel: true,
            };
            let x = Tensor::<4>::random([1, 5, 9, 7], Distribution::Default, &d).require_grad();
            let probe = Tensor::<4>::random([1, 6, 9, 7], Distribution::Default, &d);
            // Value and input gradient against Burn's conv2d.
            let check = |w: Tensor<4>, what: &str| {
                let y = conv2d(x.clone(), w.clone(), None, params);
                let opts = ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
                let y_ref = burn_conv2d(x.clone(), w, None, opts);
                close(y.clone(), y_ref.clone(), tol, &format!("y {what}"));
                let g = (y * probe.clone()).sum().backward();
                let g_ref = (y_ref * probe.clone()).sum().backward();
                let (dx, dx_ref) = (x.grad(&g).unwrap(), x.grad(&g_ref).unwrap());
                close(dx, dx_ref, tol, &format!("dx {what}"));
            };
            let w = Tensor::<4>::random([6, 5, 3, 3], Distribution::Normal(0.0, 0.3), &d);
            let before = crate::kernel_cache::built();
            check(w.clone(), &format!("{engine:?} first call"));
            assert_eq!(
                crate::kernel_cache::built() - before,
                per_kernel,
                "{engine:?}"
            );
            check(w.clone(), &format!("{engine:?} second call"));
            assert_eq!(
                crate::kernel_cache::built() - before,
                per_kernel,
                "{engine:?}: the second call rebuilt the kernel matrices"
            );
            // `w` is this test's only handle: an in-place add would reuse its storage, but the
            // cache holds it too, so Flex copies, and the new values get new matrices.
            let changed = w.add_scalar(1.0);
            check(changed, &format!("{engine:?} changed kernel"));
            assert_eq!(
                crate::kernel_cache::built() - before,
                2 * per_kernel,
                "{engine:?}"
            );
        }
    }
}
