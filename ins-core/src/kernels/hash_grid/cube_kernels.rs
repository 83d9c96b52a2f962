//! The hash encoding's CubeCL device code: where a point falls in a level, the corner rows and
//! weights, and the three kernels [`super::cube`] launches. The same maths and conventions as
//! [`super::kernel`] (clamping, dense and hashed levels, the 32-bit hash).

use cubecl::prelude::*;

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
pub(super) trait ScatterAdd: Send + Sync + 'static {
    /// What the gradient buffer holds: f32, or its bits as u32.
    type Proxy: Numeric;

    fn add(cell: &mut Atomic<Self::Proxy>, value: f32);
}

/// The device's atomic float add.
#[derive(CubeType)]
pub(super) struct NativeAdd;

/// A compare-and-swap loop on the value's bits, for devices without atomic float adds.
#[derive(CubeType)]
pub(super) struct SwapAdd;

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
pub(super) fn lookup_kernel(
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
pub(super) fn scatter_kernel<A: ScatterAdd>(
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
pub(super) fn backward_positions_kernel(
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
