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
use burn::backend::Shape;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::{empty_device_dtype, zeros_client};
use burn_cubecl::tensor::CubeTensor;
use cubecl::features::AtomicUsage;
use cubecl::ir::{ElemType, FloatKind, Type};
use cubecl::prelude::*;
use cubecl::{CubeDim, calculate_cube_count_elemwise};

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

/// Lower cell corner of coordinate `p` (clamped to `[0, 1]`) at resolution `res`.
#[cube]
fn lower(p: f32, res: u32) -> u32 {
    let x = f32::clamp(p, 0.0, 1.0) * f32::cast_from(res);
    min(u32::cast_from(x), res - 1)
}

/// Fraction of coordinate `p` within the cell whose lower corner is `i`.
#[cube]
fn fraction(p: f32, res: u32, i: u32) -> f32 {
    f32::clamp(p, 0.0, 1.0) * f32::cast_from(res) - f32::cast_from(i)
}

/// Where a point falls in one level: its cell's lower corner and the fractions within it.
#[derive(CubeType)]
struct Cell {
    ix: u32,
    iy: u32,
    iz: u32,
    fx: f32,
    fy: f32,
    fz: f32,
}

/// The cell of point `p` at resolution `res`.
#[cube]
fn cell(positions: &[f32], p: usize, res: u32) -> Cell {
    let (px, py, pz) = (positions[p * 3], positions[p * 3 + 1], positions[p * 3 + 2]);
    let (ix, iy, iz) = (lower(px, res), lower(py, res), lower(pz, res));
    Cell {
        ix,
        iy,
        iz,
        fx: fraction(px, res, ix),
        fy: fraction(py, res, iy),
        fz: fraction(pz, res, iz),
    }
}

/// A corner's interpolation factor along one axis: `f` on the upper side, `1 − f` below.
#[cube]
fn factor(bit: u32, f: f32) -> f32 {
    let mut t = 1.0 - f;
    if bit == 1 {
        t = f;
    }
    t
}

/// The derivative of [`factor`] with respect to the position: `±resolution`.
#[cube]
fn slope(bit: u32, res: f32) -> f32 {
    let mut s = -res;
    if bit == 1 {
        s = res;
    }
    s
}

/// 1 where the coordinate lies inside `[0, 1]` (where it moves the encoding), else 0.
#[cube]
fn inside(p: f32) -> f32 {
    let mut v = 0.0;
    if p >= 0.0 && p <= 1.0 {
        v = 1.0;
    }
    v
}

/// Table row of corner `c` (bits x, y, z) of cell `k` in level `l`; the same row as
/// [`Layout::row`].
#[cube]
fn corner_row(levels: &[u32], l: usize, k: &Cell, c: u32) -> usize {
    let x = k.ix + (c & 1);
    let y = k.iy + ((c >> 1) & 1);
    let z = k.iz + ((c >> 2) & 1);
    let res = levels[l * 4];
    let mut local = (x ^ (y * 2_654_435_761u32) ^ (z * 805_459_861u32)) & levels[l * 4 + 2];
    if levels[l * 4 + 3] == 1 {
        let v = res + 1;
        local = x + y * v + z * v * v;
    }
    usize::cast_from(levels[l * 4 + 1] + local)
}

/// How a unit adds its share into a table row other units may be adding to.
#[cube]
trait ScatterAdd: Send + Sync + 'static {
    /// What the gradient buffer holds: f32, or its bits as u32.
    type Proxy: Numeric;

    fn add(cell: &mut Atomic<Self::Proxy>, value: f32);
}

/// The device's atomic float add.
#[derive(CubeType)]
struct NativeAdd;

/// A compare-and-swap loop on the value's bits, for devices without atomic float adds.
#[derive(CubeType)]
struct SwapAdd;

#[cube]
impl ScatterAdd for NativeAdd {
    type Proxy = f32;

    fn add(cell: &mut Atomic<f32>, value: f32) {
        cell.fetch_add(value);
    }
}

#[cube]
impl ScatterAdd for SwapAdd {
    type Proxy = u32;

    fn add(cell: &mut Atomic<u32>, value: f32) {
        let mut v = cell.load();
        loop {
            let prev = v;
            let next = (f32::from_bits(v) + value).to_bits();
            v = cell.compare_exchange_weak(v, next);
            if prev == v {
                break;
            }
        }
    }
}

/// The encoding (`out[p, l·F + f]`) or, with `jacobian`, its spatial derivative
/// (`out[p, l·F + f, k]`, zero along an axis where the point is clamped): one unit per
/// (point, level).
#[cube(launch)]
fn lookup_kernel(
    positions: &[f32],
    table: &[f32],
    levels: &[u32],
    out: &mut [f32],
    #[comptime] num_levels: usize,
    #[comptime] features: usize,
    #[comptime] jacobian: bool,
) {
    let n = positions.len() / 3;
    if ABSOLUTE_POS >= n * num_levels {
        terminate!();
    }
    let p = ABSOLUTE_POS / num_levels;
    let l = ABSOLUTE_POS % num_levels;
    let res = levels[l * 4];
    let rf = f32::cast_from(res);
    let k = cell(positions, p, res);
    #[unroll]
    for f in 0..features {
        let mut v = 0.0f32;
        let mut jx = 0.0f32;
        let mut jy = 0.0f32;
        let mut jz = 0.0f32;
        for c in 0..8u32 {
            let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let (tx, ty, tz) = (factor(bx, k.fx), factor(by, k.fy), factor(bz, k.fz));
            let t = table[corner_row(levels, l, &k, c) * features + f];
            if jacobian {
                jx += slope(bx, rf) * ty * tz * t;
                jy += tx * slope(by, rf) * tz * t;
                jz += tx * ty * slope(bz, rf) * t;
            } else {
                v += tx * ty * tz * t;
            }
        }
        let e = (p * num_levels + l) * features + f;
        if jacobian {
            out[e * 3] = jx * inside(positions[p * 3]);
            out[e * 3 + 1] = jy * inside(positions[p * 3 + 1]);
            out[e * 3 + 2] = jz * inside(positions[p * 3 + 2]);
        } else {
            out[e] = v;
        }
    }
}

/// `∂L/∂table` for an upstream gradient of the encoding (`[N, L·F]`: weight · upstream) or,
/// with `jacobian`, of its Jacobian (`[N, L·F, 3]`: the weights' derivatives · upstream),
/// scattered into the 8 corner rows of each (point, level).
#[cube(launch)]
fn scatter_kernel<A: ScatterAdd>(
    positions: &[f32],
    upstream: &[f32],
    levels: &[u32],
    grad_table: &mut [Atomic<A::Proxy>],
    #[comptime] num_levels: usize,
    #[comptime] features: usize,
    #[comptime] jacobian: bool,
) {
    let n = positions.len() / 3;
    if ABSOLUTE_POS >= n * num_levels {
        terminate!();
    }
    let p = ABSOLUTE_POS / num_levels;
    let l = ABSOLUTE_POS % num_levels;
    let res = levels[l * 4];
    let rf = f32::cast_from(res);
    let (mx, my, mz) = (
        inside(positions[p * 3]),
        inside(positions[p * 3 + 1]),
        inside(positions[p * 3 + 2]),
    );
    let k = cell(positions, p, res);
    for c in 0..8u32 {
        let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let (tx, ty, tz) = (factor(bx, k.fx), factor(by, k.fy), factor(bz, k.fz));
        let row = corner_row(levels, l, &k, c);
        #[unroll]
        for f in 0..features {
            let e = (p * num_levels + l) * features + f;
            let g = if jacobian {
                slope(bx, rf) * ty * tz * mx * upstream[e * 3]
                    + tx * slope(by, rf) * tz * my * upstream[e * 3 + 1]
                    + tx * ty * slope(bz, rf) * mz * upstream[e * 3 + 2]
            } else {
                tx * ty * tz * upstream[e]
            };
            if g != 0.0 {
                A::add(&mut grad_table[row * features + f], g);
            }
        }
    }
}

/// `∂L/∂positions`: one unit per point, over all levels.
#[cube(launch)]
fn backward_positions_kernel(
    positions: &[f32],
    table: &[f32],
    grad_out: &[f32],
    levels: &[u32],
    grad_positions: &mut [f32],
    #[comptime] num_levels: usize,
    #[comptime] features: usize,
) {
    let n = positions.len() / 3;
    if ABSOLUTE_POS >= n {
        terminate!();
    }
    let p = ABSOLUTE_POS;
    let (px, py, pz) = (positions[p * 3], positions[p * 3 + 1], positions[p * 3 + 2]);
    let mut gx = 0.0f32;
    let mut gy = 0.0f32;
    let mut gz = 0.0f32;
    for l in 0..num_levels {
        let res = levels[l * 4];
        let rf = f32::cast_from(res);
        let k = cell(positions, p, res);
        for c in 0..8u32 {
            let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let (tx, ty, tz) = (factor(bx, k.fx), factor(by, k.fy), factor(bz, k.fz));
            let row = corner_row(levels, l, &k, c);
            let mut dot = 0.0f32;
            #[unroll]
            for f in 0..features {
                dot += table[row * features + f] * grad_out[(p * num_levels + l) * features + f];
            }
            gx += slope(bx, rf) * ty * tz * dot;
            gy += tx * slope(by, rf) * tz * dot;
            gz += tx * ty * slope(bz, rf) * dot;
        }
    }
    grad_positions[p * 3] = gx * inside(px);
    grad_positions[p * 3 + 1] = gy * inside(py);
    grad_positions[p * 3 + 2] = gz * inside(pz);
}

/// Launch sizes for `units` independent units.
fn grid(t: &CubeTensor, units: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new(&t.client, units);
    (calculate_cube_count_elemwise(&t.client, units, dim), dim)
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

fn empty_like(t: &CubeTensor, shape: impl Into<Shape>) -> CubeTensor {
    empty_device_dtype(t.client.clone(), t.device.clone(), shape.into(), DType::F32)
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
    let grad = zeros_client(
        positions.client.clone(),
        positions.device.clone(),
        [layout.total_rows(), layout.features].into(),
        DType::F32,
    );
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
    use crate::modules::hash_grid::kernel;

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
