//! The hash encoding as a Burn op with a hand-written backward: the plain-Rust kernels of
//! [`super::kernel`] on the CPU backend (Flex), the CubeCL kernels of [`super::cube`]
//! on the GPU ones (through Fusion, as an opaque operation), and under autodiff.
//!
//! Through ordinary Burn ops the encoding is 8·L gathers per point, each with a scatter-add in
//! backward that Flex runs as a sequential loop; the kernel does a point's whole encoding in
//! one pass and accumulates the table gradient level by level in parallel. Backends without
//! the op (LibTorch, Remote) use [`super::reference`], built from ordinary differentiable ops.

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, DispatchDevice, Flex, Shape, TensorData,
    TensorMetadata, backend_extension,
};
use burn::prelude::*;

use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

use super::cube;
use super::kernel::{self, GridShape};

/// The hash encoding's forward, backward and Jacobian as backend operations.
#[backend_extension(Flex, Cube, Fusion, Autodiff)]
pub trait HashGridOps: Backend {
    /// `positions [N, 3]` in `[0, 1]`, `table [R, F]` → `[N, L·F]`.
    #[fusion(dtype = positions, shape = Shape::new([positions[0], shape.d_out()]))]
    fn hash_grid_forward(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self>;

    /// `∂L/∂table` (`[R, F]`) for upstream `grad_out [N, L·F]`.
    #[fusion(dtype = positions, shape = table_shape(shape))]
    fn hash_grid_backward_table(
        positions: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self>;

    /// `∂L/∂positions` (`[N, 3]`) for upstream `grad_out [N, L·F]`.
    #[fusion(dtype = positions, shape = positions)]
    fn hash_grid_backward_positions(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self>;

    /// The spatial Jacobian `[N, L·F, 3]`.
    #[fusion(dtype = positions, shape = Shape::new([positions[0], shape.d_out(), 3]))]
    fn hash_grid_jacobian(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self>;

    /// `∂L/∂table` for upstream `grad_jac [N, L·F, 3]` of the Jacobian.
    #[fusion(dtype = positions, shape = table_shape(shape))]
    fn hash_grid_jacobian_backward_table(
        positions: FloatTensor<Self>,
        grad_jac: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self>;
}

/// The table's shape `[R, F]`, for Fusion to describe a table gradient before it runs.
fn table_shape(shape: &GridShape) -> Shape {
    Shape::new([shape.layout().total_rows(), shape.features as usize])
}

/// Runs `f` on the f32 values of a Flex tensor, without a copy when it is contiguous.
fn flex_values<R>(t: &FlexTensor, f: impl FnOnce(&[f32]) -> R) -> R {
    assert_eq!(t.dtype(), DType::F32, "the hash encoding runs in f32");
    let t = t.to_contiguous();
    f(t.as_slice::<f32>().expect("contiguous f32"))
}

fn flex_from(values: Vec<f32>, shape: impl Into<burn::backend::Shape>) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape.into()))
}

/// A table's gradient, zeroed by all threads: it is tens of MB (the colour grid's 12.2 M
/// floats), and one thread's memset left the other cores idle for a few ms every step.
fn zeroed_table(layout: &kernel::Layout) -> Vec<f32> {
    let n = layout.total_rows() * layout.features;
    crate::kernels::flex::filled(n, |_, chunk| chunk.fill(std::mem::MaybeUninit::new(0.0)))
}

fn rows(t: &impl TensorMetadata) -> usize {
    t.shape()[0]
}

impl HashGridOps for Flex {
    fn hash_grid_forward(positions: FlexTensor, table: FlexTensor, shape: GridShape) -> FlexTensor {
        let layout = shape.layout();
        let n = rows(&positions);
        let mut out = vec![0.0; n * shape.d_out()];
        flex_values(&positions, |p| {
            flex_values(&table, |t| kernel::forward(&layout, t, p, &mut out))
        });
        flex_from(out, [n, shape.d_out()])
    }

    fn hash_grid_backward_table(
        positions: FlexTensor,
        grad_out: FlexTensor,
        shape: GridShape,
    ) -> FlexTensor {
        let layout = shape.layout();
        let mut g = zeroed_table(&layout);
        flex_values(&positions, |p| {
            flex_values(&grad_out, |go| {
                kernel::backward_table(&layout, p, go, &mut g)
            })
        });
        flex_from(g, [layout.total_rows(), layout.features])
    }

    fn hash_grid_backward_positions(
        positions: FlexTensor,
        table: FlexTensor,
        grad_out: FlexTensor,
        shape: GridShape,
    ) -> FlexTensor {
        let layout = shape.layout();
        let n = rows(&positions);
        let mut g = vec![0.0; n * 3];
        flex_values(&positions, |p| {
            flex_values(&table, |t| {
                flex_values(&grad_out, |go| {
                    kernel::backward_positions(&layout, t, p, go, &mut g)
                })
            })
        });
        flex_from(g, [n, 3])
    }

    fn hash_grid_jacobian(
        positions: FlexTensor,
        table: FlexTensor,
        shape: GridShape,
    ) -> FlexTensor {
        let layout = shape.layout();
        let n = rows(&positions);
        let mut j = vec![0.0; n * shape.d_out() * 3];
        flex_values(&positions, |p| {
            flex_values(&table, |t| kernel::jacobian(&layout, t, p, &mut j))
        });
        flex_from(j, [n, shape.d_out(), 3])
    }

    fn hash_grid_jacobian_backward_table(
        positions: FlexTensor,
        grad_jac: FlexTensor,
        shape: GridShape,
    ) -> FlexTensor {
        let layout = shape.layout();
        let mut g = zeroed_table(&layout);
        flex_values(&positions, |p| {
            flex_values(&grad_jac, |gj| {
                kernel::jacobian_backward_table(&layout, p, gj, &mut g)
            })
        });
        flex_from(g, [layout.total_rows(), layout.features])
    }
}

impl HashGridOps for CubeBackend {
    fn hash_grid_forward(positions: CubeTensor, table: CubeTensor, shape: GridShape) -> CubeTensor {
        cube::forward(positions, table, shape)
    }

    fn hash_grid_backward_table(
        positions: CubeTensor,
        grad_out: CubeTensor,
        shape: GridShape,
    ) -> CubeTensor {
        cube::backward_table(positions, grad_out, shape)
    }

    fn hash_grid_backward_positions(
        positions: CubeTensor,
        table: CubeTensor,
        grad_out: CubeTensor,
        shape: GridShape,
    ) -> CubeTensor {
        cube::backward_positions(positions, table, grad_out, shape)
    }

    fn hash_grid_jacobian(
        positions: CubeTensor,
        table: CubeTensor,
        shape: GridShape,
    ) -> CubeTensor {
        cube::jacobian(positions, table, shape)
    }

    fn hash_grid_jacobian_backward_table(
        positions: CubeTensor,
        grad_jac: CubeTensor,
        shape: GridShape,
    ) -> CubeTensor {
        cube::jacobian_backward_table(positions, grad_jac, shape)
    }
}

#[derive(Debug)]
struct EncodeBackward;

impl<B: Backend + HashGridOps> Backward<B, 2> for EncodeBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, GridShape);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [positions_node, table_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (positions, table, shape) = ops.state;
        if let Some(node) = table_node {
            let g = B::hash_grid_backward_table(positions.clone(), grad.clone(), shape);
            grads.register::<B>(node.id, g);
        }
        if let Some(node) = positions_node {
            let g = B::hash_grid_backward_positions(positions, table, grad, shape);
            grads.register::<B>(node.id, g);
        }
    }
}

#[derive(Debug)]
struct JacobianBackward;

impl<B: Backend + HashGridOps> Backward<B, 2> for JacobianBackward {
    type State = (FloatTensor<B>, GridShape);

    /// The Jacobian's gradient reaches the table; its dependence on the positions (second
    /// derivatives of the encoding) is not propagated: normals are taken at given points.
    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [_, table_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (positions, shape) = ops.state;
        if let Some(node) = table_node {
            let g = B::hash_grid_jacobian_backward_table(positions, grad, shape);
            grads.register::<B>(node.id, g);
        }
    }
}

impl<B: Backend + HashGridOps, C: CheckpointStrategy> HashGridOps for Autodiff<B, C> {
    fn hash_grid_forward(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self> {
        match EncodeBackward
            .prepare::<C>([positions.node(), table.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let p = positions.into_primitive();
                let t = table.into_primitive();
                let out = B::hash_grid_forward(p.clone(), t.clone(), shape);
                prep.finish((p, t, shape), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::hash_grid_forward(
                positions.into_primitive(),
                table.into_primitive(),
                shape,
            )),
        }
    }

    fn hash_grid_jacobian(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self> {
        match JacobianBackward
            .prepare::<C>([positions.node(), table.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let p = positions.into_primitive();
                let out = B::hash_grid_jacobian(p.clone(), table.into_primitive(), shape);
                prep.finish((p, shape), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::hash_grid_jacobian(
                positions.into_primitive(),
                table.into_primitive(),
                shape,
            )),
        }
    }

    fn hash_grid_backward_table(
        positions: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::hash_grid_backward_table(
            positions.into_primitive(),
            grad_out.into_primitive(),
            shape,
        ))
    }

    fn hash_grid_backward_positions(
        positions: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad_out: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::hash_grid_backward_positions(
            positions.into_primitive(),
            table.into_primitive(),
            grad_out.into_primitive(),
            shape,
        ))
    }

    fn hash_grid_jacobian_backward_table(
        positions: FloatTensor<Self>,
        grad_jac: FloatTensor<Self>,
        shape: GridShape,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::hash_grid_jacobian_backward_table(
            positions.into_primitive(),
            grad_jac.into_primitive(),
            shape,
        ))
    }
}

/// Whether the kernels run on this device (Flex or a CubeCL runtime, with or without
/// autodiff).
pub fn kernel_device(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Flex(_) | DispatchDevice::Cube(_)
    )
}

/// The encoding through the kernel op. Only for devices where [`kernel_device`] holds.
pub fn encode_kernel(positions: Tensor<2>, table: Tensor<2>, shape: GridShape) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as HashGridOps>::hash_grid_forward(
        positions.into_dispatch(),
        table.into_dispatch(),
        shape,
    ))
}

/// The Jacobian through the kernel op. Only for devices where [`kernel_device`] holds.
pub fn jacobian_kernel(positions: Tensor<2>, table: Tensor<2>, shape: GridShape) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as HashGridOps>::hash_grid_jacobian(
        positions.into_dispatch(),
        table.into_dispatch(),
        shape,
    ))
}
