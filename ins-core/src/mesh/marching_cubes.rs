//! Iso-surface extraction from a sampled scalar field with classic
//! Lorensen–Cline marching cubes (standard 256-case edge/triangle tables).
//!
//! * Input: a [`Grid`] of `res[0] × res[1] × res[2]` samples (x fastest) on an
//!   axis-aligned box.
//! * Output: an indexed triangle [`Mesh`] with per-vertex normals.
//! * Convention: the field is a signed distance, **negative inside**. A corner is
//!   "inside" when `value < level`. Triangles are wound counter-clockwise when seen
//!   from the side of increasing values, so face normals point outward, and vertex
//!   normals are the normalized central-difference gradient of the samples,
//!   linearly interpolated to the vertex (also outward).
//! * Every vertex lies on a grid edge and is created once per edge, so a closed
//!   surface that stays inside the box gives a watertight, consistently oriented
//!   mesh (every undirected edge is used by exactly two triangles, in opposite
//!   directions).
//! * A cube with a NaN corner produces no triangles. Gradients skip NaN neighbours
//!   when possible; if a vertex normal still cannot be computed it falls back to the
//!   area-weighted average of the adjacent face normals.
//!
//! No dependencies; memory use is the output plus a few `O(res[0]·res[1])` edge
//! caches (nothing is allocated per cube).

use super::cube_tables::{EDGE_TABLE, TRI_TABLE};
pub use super::triangle_mesh::Mesh;
use super::triangle_mesh::{cross64, norm64, sub64};

/// The grid: `res[0] × res[1] × res[2]` samples on the axis-aligned box
/// `[min, max]` (sample `(i,j,k)` at `min + (max−min)·(i,j,k)/(res−1)`), values in
/// x-fastest order (index `i + res0*(j + res1*k)`).
#[derive(Debug, Clone, Copy)]
pub struct Grid<'a> {
    /// Number of samples along x, y, z.
    pub res: [usize; 3],
    /// Position of sample `(0, 0, 0)`.
    pub min: [f32; 3],
    /// Position of sample `(res0-1, res1-1, res2-1)`.
    pub max: [f32; 3],
    /// `res0*res1*res2` samples, x fastest.
    pub values: &'a [f32],
}

/// Extracts the `level` iso-surface.
///
/// Convention: the field is a signed distance, NEGATIVE INSIDE (a sample is inside
/// when `value < level`); triangles are wound so that their normals point towards
/// increasing values (outward); per-vertex normals are the normalized
/// central-difference gradient of the grid values interpolated at the vertex
/// (pointing outward). Vertices on shared cube edges are shared, so the mesh is
/// watertight for a closed surface inside the box. Cubes with a NaN corner are
/// skipped. If any `res` component is below 2 (or `level` is NaN) the mesh is empty.
///
/// # Panics
/// If `grid.values.len() != res[0]*res[1]*res[2]`, or if the mesh would need more
/// than `u32::MAX` vertices.
pub fn marching_cubes(grid: &Grid, level: f32) -> Mesh {
    let [nx, ny, nz] = grid.res;
    let total = nx
        .checked_mul(ny)
        .and_then(|v| v.checked_mul(nz))
        .expect("marching_cubes: grid resolution overflows usize");
    assert_eq!(
        grid.values.len(),
        total,
        "marching_cubes: values.len() must equal res[0]*res[1]*res[2]"
    );
    let mut mesh = Mesh::default();
    if nx < 2 || ny < 2 || nz < 2 || level.is_nan() {
        return mesh;
    }

    let ex = Extractor::new(grid, level);
    let values = grid.values;
    let (sy, sz) = (nx, nx * ny);

    // Edge -> vertex caches. x- and y-edges of the lower (z = k) and upper
    // (z = k+1) sample layers of the current slab, and the z-edges between them.
    let mut xe_lo = vec![NONE; (nx - 1) * ny];
    let mut xe_hi = vec![NONE; (nx - 1) * ny];
    let mut ye_lo = vec![NONE; nx * (ny - 1)];
    let mut ye_hi = vec![NONE; nx * (ny - 1)];
    let mut ze = vec![NONE; nx * ny];
    let mut need_fallback_normals = false;

    for k in 0..nz - 1 {
        if k > 0 {
            std::mem::swap(&mut xe_lo, &mut xe_hi);
            std::mem::swap(&mut ye_lo, &mut ye_hi);
            xe_hi.fill(NONE);
            ye_hi.fill(NONE);
            ze.fill(NONE);
        }
        for j in 0..ny - 1 {
            let b00 = j * sy + k * sz;
            let r00 = &values[b00..b00 + nx]; // (y=j,   z=k)
            let r10 = &values[b00 + sy..b00 + sy + nx]; // (y=j+1, z=k)
            let r01 = &values[b00 + sz..b00 + sz + nx]; // (y=j,   z=k+1)
            let r11 = &values[b00 + sy + sz..b00 + sy + sz + nx]; // (y=j+1, z=k+1)
            for i in 0..nx - 1 {
                // Corner order of the classic tables (see CORNER_OFFSET).
                let v = [
                    r00[i],
                    r00[i + 1],
                    r10[i + 1],
                    r10[i],
                    r01[i],
                    r01[i + 1],
                    r11[i + 1],
                    r11[i],
                ];
                let mut case = 0usize;
                for (c, &val) in v.iter().enumerate() {
                    case |= usize::from(val < level) << c;
                }
                // A NaN corner never sets its bit, so an all-NaN/outside cube is 0;
                // a NaN cube can never be 255.
                if case == 0 || case == 255 || v.iter().any(|x| x.is_nan()) {
                    continue;
                }

                let edges = EDGE_TABLE[case];
                let mut ev = [0u32; 12];
                for (e, slot_out) in ev.iter_mut().enumerate() {
                    if edges & (1 << e) == 0 {
                        continue;
                    }
                    let slot = match e {
                        0 => &mut xe_lo[i + (nx - 1) * j],
                        2 => &mut xe_lo[i + (nx - 1) * (j + 1)],
                        4 => &mut xe_hi[i + (nx - 1) * j],
                        6 => &mut xe_hi[i + (nx - 1) * (j + 1)],
                        3 => &mut ye_lo[i + nx * j],
                        1 => &mut ye_lo[i + 1 + nx * j],
                        7 => &mut ye_hi[i + nx * j],
                        5 => &mut ye_hi[i + 1 + nx * j],
                        8 => &mut ze[i + nx * j],
                        9 => &mut ze[i + 1 + nx * j],
                        11 => &mut ze[i + nx * (j + 1)],
                        _ => &mut ze[i + 1 + nx * (j + 1)], // 10
                    };
                    if *slot == NONE {
                        let (lo, hi, axis) = EDGE_CORNERS[e];
                        let o = CORNER_OFFSET[lo];
                        let ok = ex.make_vertex(
                            &mut mesh,
                            [i + o[0], j + o[1], k + o[2]],
                            axis,
                            v[lo],
                            v[hi],
                        );
                        need_fallback_normals |= !ok;
                        *slot = u32::try_from(mesh.vertices.len() - 1)
                            .expect("marching_cubes: more than u32::MAX vertices");
                    }
                    *slot_out = *slot;
                }

                let tri = &TRI_TABLE[case];
                let mut t = 0;
                while t < 16 && tri[t] >= 0 {
                    let a = ev[tri[t] as usize];
                    let b = ev[tri[t + 1] as usize];
                    let c = ev[tri[t + 2] as usize];
                    // The classic table winds triangles towards the inside (for a
                    // right-handed box); flip so normals point to increasing values.
                    mesh.triangles
                        .push(if ex.flip { [a, b, c] } else { [a, c, b] });
                    t += 3;
                }
            }
        }
    }

    if need_fallback_normals {
        fallback_normals(&mut mesh);
    }
    mesh
}

const NONE: u32 = u32::MAX;

/// Offsets of the 8 cube corners (classic numbering).
const CORNER_OFFSET: [[usize; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
];

/// For each of the 12 cube edges: (corner with the lower coordinate, other corner,
/// axis the edge runs along).
const EDGE_CORNERS: [(usize, usize, usize); 12] = [
    (0, 1, 0),
    (1, 2, 1),
    (3, 2, 0),
    (0, 3, 1),
    (4, 5, 0),
    (5, 6, 1),
    (7, 6, 0),
    (4, 7, 1),
    (0, 4, 2),
    (1, 5, 2),
    (2, 6, 2),
    (3, 7, 2),
];

struct Extractor<'g> {
    values: &'g [f32],
    res: [usize; 3],
    stride: [usize; 3],
    /// Sample coordinates along each axis.
    coords: [Vec<f32>; 3],
    /// Sample spacing along each axis (may be negative if max < min).
    spacing: [f32; 3],
    level: f32,
    /// Reverse the winding (an odd number of axes has max < min).
    flip: bool,
}

impl<'g> Extractor<'g> {
    fn new(grid: &Grid<'g>, level: f32) -> Self {
        let res = grid.res;
        let coords = std::array::from_fn(|a| {
            let d = (res[a] - 1) as f32;
            (0..res[a])
                .map(|i| grid.min[a] + (grid.max[a] - grid.min[a]) * (i as f32) / d)
                .collect()
        });
        let spacing: [f32; 3] =
            std::array::from_fn(|a| (grid.max[a] - grid.min[a]) / (res[a] - 1) as f32);
        let negatives = spacing.iter().filter(|h| **h < 0.0).count();
        Extractor {
            values: grid.values,
            res,
            stride: [1, res[0], res[0] * res[1]],
            coords,
            spacing,
            level,
            flip: negatives % 2 == 1,
        }
    }

    /// Appends the vertex on the edge from sample `p` to `p + e_axis` (values
    /// `v0`, `v1`). Returns false if its normal could not be computed.
    fn make_vertex(&self, mesh: &mut Mesh, p: [usize; 3], axis: usize, v0: f32, v1: f32) -> bool {
        let d = v1 - v0;
        let t = if d != 0.0 {
            ((self.level - v0) / d).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let mut pos = [
            self.coords[0][p[0]],
            self.coords[1][p[1]],
            self.coords[2][p[2]],
        ];
        let c0 = self.coords[axis][p[axis]];
        let c1 = self.coords[axis][p[axis] + 1];
        pos[axis] = c0 + t * (c1 - c0);

        let mut q = p;
        q[axis] += 1;
        let g0 = self.gradient(p);
        let g1 = self.gradient(q);
        let g: [f32; 3] = std::array::from_fn(|a| g0[a] + t * (g1[a] - g0[a]));
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let (n, ok) = if len.is_finite() && len > 0.0 {
            (g.map(|x| x / len), true)
        } else {
            ([0.0; 3], false)
        };
        mesh.vertices.push(pos);
        mesh.normals.push(n);
        ok
    }

    /// Finite-difference gradient at sample `p`: central where possible, one-sided
    /// at the border or next to NaN samples; a component is 0 if none is finite.
    fn gradient(&self, p: [usize; 3]) -> [f32; 3] {
        let idx = p[0] + self.stride[1] * p[1] + self.stride[2] * p[2];
        let f0 = self.values[idx];
        std::array::from_fn(|a| {
            let (c, n, s, h) = (p[a], self.res[a], self.stride[a], self.spacing[a]);
            let fwd = (c + 1 < n).then(|| self.values[idx + s]);
            let bwd = (c > 0).then(|| self.values[idx - s]);
            let candidates = [
                match (fwd, bwd) {
                    (Some(f), Some(b)) => (f - b) / (2.0 * h),
                    _ => f32::NAN,
                },
                fwd.map_or(f32::NAN, |f| (f - f0) / h),
                bwd.map_or(f32::NAN, |b| (f0 - b) / h),
            ];
            candidates
                .into_iter()
                .find(|x| x.is_finite())
                .unwrap_or(0.0)
        })
    }
}

/// Replaces zero normals by the normalized sum of adjacent (area-weighted) face
/// normals.
fn fallback_normals(mesh: &mut Mesh) {
    let mut acc = vec![[0.0f64; 3]; mesh.vertices.len()];
    let missing: Vec<bool> = mesh.normals.iter().map(|n| *n == [0.0; 3]).collect();
    for t in &mesh.triangles {
        if !t.iter().any(|&i| missing[i as usize]) {
            continue;
        }
        let [a, b, c] = mesh.tri_f64(t);
        let n = cross64(sub64(b, a), sub64(c, a));
        for &i in t {
            for d in 0..3 {
                acc[i as usize][d] += n[d];
            }
        }
    }
    for (i, n) in mesh.normals.iter_mut().enumerate() {
        if missing[i] {
            let len = norm64(acc[i]);
            if len > 0.0 && len.is_finite() {
                *n = acc[i].map(|x| (x / len) as f32);
            }
        }
    }
}

#[cfg(test)]
#[path = "marching_cubes_tests.rs"]
pub(crate) mod tests;
