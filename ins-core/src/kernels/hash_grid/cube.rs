//! The hash encoding as CubeCL kernels, for the GPU backends (wgpu, CUDA, ROCm, Metal).
//!
//! The same maths as [`super::kernel`], one unit per (point, level): its cell, its 8 corner
//! rows and their trilinear weights (or their spatial derivatives). Table gradients are
//! scatter-adds into shared rows, done with atomic float adds where the device has them, and
//! with a compare-and-swap loop on the bits where it has not (WebGPU, some drivers).
//!
//! Through ordinary Burn ops the encoding is 8·L gathers per point, each its own kernel with an
//! index tensor in memory, and the backward a scatter per gather; here it is one kernel.

use burn::backend::DType;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::features::AtomicUsage;
use cubecl::ir::{ElemType, FloatKind, Type};
use cubecl::prelude::*;

use crate::kernels::cube_launch::{empty_like, grid, zeros_like};

use super::cube_kernels::{
    NativeAdd, SwapAdd, backward_positions_kernel, lookup_kernel, scatter_kernel,
};
use super::kernel::{GridShape, Layout};

/// `(resolution, first row, hash mask or 0, dense 1/0)` of each level, as the kernels read it.
fn level_records(layout: &Layout) -> Vec<u32> {
    (0..layout.levels())
        .flat_map(|l| {
            let mask = if layout.dense[l] {
                0
            } else {
                layout.rows[l] as u32 - 1
            };
            [
                layout.resolution[l],
                layout.offset[l] as u32,
                mask,
                layout.dense[l] as u32,
            ]
        })
        .collect()
}

/// The layout's level records on the tensor's device.
fn levels_arg(t: &CubeTensor, layout: &Layout) -> BufferArg {
    let records = level_records(layout);
    let handle = t.client.create_from_slice(u32::as_bytes(&records));
    // SAFETY: the buffer holds exactly `records.len()` u32 values.
    unsafe { BufferArg::from_raw_parts(handle, records.len()) }
}

fn contiguous_f32(t: CubeTensor, what: &str) -> CubeTensor {
    assert_eq!(
        t.dtype,
        DType::F32,
        "the hash encoding runs in f32 ({what})"
    );
    into_contiguous(t)
}

/// How the table gradients are accumulated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Adder {
    /// The device's atomic float add.
    Native,
    /// Compare-and-swap on the bits.
    Swap,
}

impl Adder {
    /// The native add where the device has it, else the swap loop.
    pub fn for_device(t: &CubeTensor) -> Self {
        let native = t
            .client
            .properties()
            .atomic_type_usage(Type::atomic(ElemType::Float(FloatKind::F32)))
            .contains(AtomicUsage::Add);
        if native { Self::Native } else { Self::Swap }
    }
}

/// `positions [N, 3]`, `table [R, F]` → `[N, L·F]`.
pub fn forward(positions: CubeTensor, table: CubeTensor, shape: GridShape) -> CubeTensor {
    lookup(positions, table, shape, false)
}

/// The spatial Jacobian `[N, L·F, 3]`.
pub fn jacobian(positions: CubeTensor, table: CubeTensor, shape: GridShape) -> CubeTensor {
    lookup(positions, table, shape, true)
}

/// The encoding, or its Jacobian: one unit per (point, level) reading the table.
fn lookup(
    positions: CubeTensor,
    table: CubeTensor,
    shape: GridShape,
    jacobian: bool,
) -> CubeTensor {
    let layout = shape.layout();
    let n = positions.meta.shape()[0];
    let (positions, table) = (
        contiguous_f32(positions, "positions"),
        contiguous_f32(table, "table"),
    );
    let out = if jacobian {
        empty_like(&positions, [n, shape.d_out(), 3])
    } else {
        empty_like(&positions, [n, shape.d_out()])
    };
    if n == 0 {
        return out;
    }
    let (count, dim) = grid(&positions, n * layout.levels());
    let levels = levels_arg(&positions, &layout);
    lookup_kernel::launch(
        &positions.client.clone(),
        count,
        dim,
        positions.into_buffer_arg(),
        table.into_buffer_arg(),
        levels,
        out.clone().into_buffer_arg(),
        layout.levels(),
        layout.features,
        jacobian,
    );
    out
}

/// `∂L/∂positions [N, 3]` for upstream `grad_out [N, L·F]`.
pub fn backward_positions(
    positions: CubeTensor,
    table: CubeTensor,
    grad_out: CubeTensor,
    shape: GridShape,
) -> CubeTensor {
    let layout = shape.layout();
    let n = positions.meta.shape()[0];
    let positions = contiguous_f32(positions, "positions");
    let table = contiguous_f32(table, "table");
    let grad_out = contiguous_f32(grad_out, "upstream gradient");
    let out = empty_like(&positions, [n, 3]);
    if n == 0 {
        return out;
    }
    let (count, dim) = grid(&positions, n);
    let levels = levels_arg(&positions, &layout);
    backward_positions_kernel::launch(
        &positions.client.clone(),
        count,
        dim,
        positions.into_buffer_arg(),
        table.into_buffer_arg(),
        grad_out.into_buffer_arg(),
        levels,
        out.clone().into_buffer_arg(),
        layout.levels(),
        layout.features,
    );
    out
}

/// `∂L/∂table [R, F]` for upstream `grad_out [N, L·F]`.
pub fn backward_table(positions: CubeTensor, grad_out: CubeTensor, shape: GridShape) -> CubeTensor {
    let adder = Adder::for_device(&positions);
    table_gradient(positions, grad_out, shape, adder, false)
}

/// `∂L/∂table [R, F]` for upstream `grad_jac [N, L·F, 3]` of the Jacobian.
pub fn jacobian_backward_table(
    positions: CubeTensor,
    grad_jac: CubeTensor,
    shape: GridShape,
) -> CubeTensor {
    let adder = Adder::for_device(&positions);
    table_gradient(positions, grad_jac, shape, adder, true)
}

/// The table gradient for an upstream gradient of the encoding (`[N, L·F]`) or of its Jacobian
/// (`[N, L·F, 3]`), accumulated with `adder` into zeros: one unit per (point, level).
pub fn table_gradient(
    positions: CubeTensor,
    upstream: CubeTensor,
    shape: GridShape,
    adder: Adder,
    jacobian: bool,
) -> CubeTensor {
    let layout = shape.layout();
    let n = positions.meta.shape()[0];
    let positions = contiguous_f32(positions, "positions");
    let upstream = contiguous_f32(upstream, "upstream gradient");
    let grad = zeros_like(&positions, [layout.total_rows(), layout.features]);
    if n == 0 {
        return grad;
    }
    let (count, dim) = grid(&positions, n * layout.levels());
    let levels = levels_arg(&positions, &layout);
    let launch = match adder {
        Adder::Native => scatter_kernel::launch::<NativeAdd>,
        Adder::Swap => scatter_kernel::launch::<SwapAdd>,
    };
    // The swap loop reads the f32 zeros as u32 zeros: the same bits.
    launch(
        &positions.client.clone(),
        count,
        dim,
        positions.into_buffer_arg(),
        upstream.into_buffer_arg(),
        levels,
        grad.clone().into_buffer_arg(),
        layout.levels(),
        layout.features,
        jacobian,
    );
    grad
}

#[cfg(test)]
mod tests {
    use std::sync::mpsc;
    use std::time::Duration;

    use burn::backend::ops::FloatTensorOps;
    use burn::backend::{DispatchDevice, TensorData, read_sync};
    use burn_cubecl::{CubeBackend, CubeDevice};

    use super::*;
    use crate::backend::BackendChoice;
    use crate::kernels::hash_grid::kernel;

    /// Hashed levels with a table small enough that many points share rows.
    fn shape() -> GridShape {
        GridShape {
            levels: 3,
            features: 2,
            log2_table: 6,
            base_resolution: 3,
            max_resolution: 24,
        }
    }

    fn wgpu_device() -> CubeDevice {
        match BackendChoice::Wgpu.device().inner().as_dispatch() {
            DispatchDevice::Cube(d) => d.clone(),
            _ => unreachable!("wgpu is a CubeCL device"),
        }
    }

    fn upload(values: &[f32], shape: &[usize], device: &CubeDevice) -> CubeTensor {
        CubeBackend::float_from_data(TensorData::new(values.to_vec(), shape.to_vec()), device)
    }

    fn download(t: CubeTensor) -> Vec<f32> {
        read_sync(CubeBackend::float_into_data(t))
            .unwrap()
            .try_to_vec::<f32>()
            .unwrap()
    }

    /// The table gradients through each adder the device can run, against the CPU kernel.
    /// Runs under a time limit that fails the test (lavapipe compiles each kernel on the CPU).
    #[test]
    fn both_adders_scatter_the_cpu_kernels_table_gradients_on_wgpu() {
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || tx.send(compare_adders()));
        let native = rx
            .recv_timeout(Duration::from_secs(600))
            .expect("the wgpu hash-grid kernels did not finish within 600 s");
        eprintln!("wgpu adds f32 atomically: {native}");
    }

    fn compare_adders() -> bool {
        let device = wgpu_device();
        let layout = shape().layout();
        let n = 700;
        let positions: Vec<f32> = (0..n * 3)
            .map(|i| ((i * 7919) % 1009) as f32 / 1008.0 * 1.2 - 0.1)
            .collect();
        let width = shape().d_out();
        let grad_out: Vec<f32> = (0..n * width)
            .map(|i| ((i * 13) % 17) as f32 / 8.0 - 1.0)
            .collect();
        let grad_jac: Vec<f32> = (0..n * width * 3)
            .map(|i| ((i * 11) % 19) as f32 / 9.0 - 1.0)
            .collect();
        let rows = layout.total_rows() * layout.features;
        let mut want_table = vec![0.0; rows];
        kernel::backward_table(&layout, &positions, &grad_out, &mut want_table);
        let mut want_jac = vec![0.0; rows];
        kernel::jacobian_backward_table(&layout, &positions, &grad_jac, &mut want_jac);

        let native = {
            let p = upload(&positions, &[n, 3], &device);
            Adder::for_device(&p) == Adder::Native
        };
        let adders: &[Adder] = if native {
            &[Adder::Native, Adder::Swap]
        } else {
            &[Adder::Swap]
        };
        for &adder in adders {
            let p = || upload(&positions, &[n, 3], &device);
            let got = download(table_gradient(
                p(),
                upload(&grad_out, &[n, width], &device),
                shape(),
                adder,
                false,
            ));
            let got_jac = download(table_gradient(
                p(),
                upload(&grad_jac, &[n, width, 3], &device),
                shape(),
                adder,
                true,
            ));
            for (what, got, want) in [
                ("table", &got, &want_table),
                ("Jacobian table", &got_jac, &want_jac),
            ] {
                let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
                let worst = got
                    .iter()
                    .zip(want.iter())
                    .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
                assert!(
                    worst <= 1e-5 * scale,
                    "{adder:?} {what} gradient differs from the CPU kernel by {worst} (scale {scale})"
                );
            }
        }
        native
    }
}
