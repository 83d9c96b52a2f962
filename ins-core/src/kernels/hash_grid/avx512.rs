//! The hash encoding's hottest loops (a level's lookup, its table gradient, the spatial
//! Jacobian and the Jacobian's table gradient) sixteen points at a time with AVX-512, for grids
//! of two features a level (every grid the product builds).
//!
//! These loops were about 40 % of a NeRF pretraining step and of an IDR surface step, one point
//! at a time (corner hashing, weights and 16 scalar loads per point and level). Here the cell,
//! the eight weights (or their slopes) and the eight rows are computed for 16 points in vector
//! registers and each corner's feature pairs are fetched with two 64-bit gathers; the
//! gradients' adds stay one point after another. The arithmetic is the scalar loops'
//! (`super::kernel`), operation for operation, so results are bit-identical; those loops stay
//! for other CPUs, other feature counts and the last `m mod 16` points.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::kernel::Layout;

/// Points a call handles together.
pub const LANES: usize = 16;

/// Whether the vector loops can run: an x86-64 CPU with AVX-512 F, and two features a level.
pub fn usable(features: usize) -> bool {
    features == 2 && cpu_has_avx512f()
}

#[cfg(target_arch = "x86_64")]
fn cpu_has_avx512f() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| is_x86_feature_detected!("avx512f"))
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_has_avx512f() -> bool {
    false
}

/// Positions `[m, 3]` as three runs (every x, every y, every z): what 16-wide loads read.
pub fn columns(positions: &[f32]) -> Vec<f32> {
    let m = positions.len() / 3;
    let mut out = vec![0f32; 3 * m];
    for (i, p) in positions.chunks_exact(3).enumerate() {
        out[i] = p[0];
        out[m + i] = p[1];
        out[2 * m + i] = p[2];
    }
    out
}

/// Level `l`'s features of the first `16·⌊m/16⌋` points of `columns` (from [`columns`], `m`
/// points) into `dst` (`m·2`, point-major); returns how many points it wrote.
///
/// # Panics
/// Unless [`usable`] holds for the layout, or if a slice is short.
pub fn encode_level(
    layout: &Layout,
    l: usize,
    table: &[f32],
    columns: &[f32],
    dst: &mut [f32],
) -> usize {
    let m = points("encode_level", layout, columns, 2, dst.len());
    table_covers("encode_level", layout, table);
    #[cfg(target_arch = "x86_64")]
    // SAFETY: AVX-512 F is present (`usable`), and the slices are as long as checked above;
    // every row a gather reads is below `total_rows` (the level's rows are masked or bounded
    // by its resolution, as in the scalar loop).
    unsafe {
        encode(layout, l, table, columns, m, dst)
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!()
}

/// Adds level `l`'s table gradient for the first `16·⌊m/16⌋` points (`grad_level`: their
/// upstream gradient of this level, `m·2`) into `grad` (the level's own rows, `rows·2`), in the
/// scalar loop's order; returns how many points it took.
///
/// # Panics
/// Unless [`usable`] holds for the layout, or if a slice is short.
pub fn scatter_level(
    layout: &Layout,
    l: usize,
    columns: &[f32],
    grad_level: &[f32],
    grad: &mut [f32],
) -> usize {
    let m = points("scatter_level", layout, columns, 2, grad_level.len());
    level_covered("scatter_level", layout, l, grad);
    #[cfg(target_arch = "x86_64")]
    // SAFETY: as `encode_level`; rows are relative to the level and below `rows[l]`.
    unsafe {
        scatter(layout, l, columns, m, grad_level, grad)
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!()
}

/// The spatial Jacobian rows (`L·2·3` each, the axes last) of the first `16·⌊m/16⌋` points of
/// `columns` into `jac` (`m` rows), as `kernel::jacobian` sums them before it zeroes clamped
/// axes; returns how many points it wrote.
///
/// # Panics
/// Unless [`usable`] holds for the layout, or if a slice is short.
pub fn jacobian_points(layout: &Layout, table: &[f32], columns: &[f32], jac: &mut [f32]) -> usize {
    let m = points(
        "jacobian_points",
        layout,
        columns,
        layout.levels() * 6,
        jac.len(),
    );
    table_covers("jacobian_points", layout, table);
    #[cfg(target_arch = "x86_64")]
    // SAFETY: as `encode_level`.
    unsafe {
        jacobian(layout, table, columns, m, jac)
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!()
}

/// Adds level `l`'s table gradient from the Jacobian's upstream gradient `grad_jac` (`m` rows
/// of `L·2·3`) for the first `16·⌊m/16⌋` points into `grad` (the level's own rows), in
/// `kernel::jacobian_backward_table`'s order; returns how many points it took.
///
/// # Panics
/// Unless [`usable`] holds for the layout, or if a slice is short.
pub fn jacobian_scatter_level(
    layout: &Layout,
    l: usize,
    columns: &[f32],
    grad_jac: &[f32],
    grad: &mut [f32],
) -> usize {
    let m = points(
        "jacobian_scatter_level",
        layout,
        columns,
        layout.levels() * 6,
        grad_jac.len(),
    );
    level_covered("jacobian_scatter_level", layout, l, grad);
    #[cfg(target_arch = "x86_64")]
    // SAFETY: as `scatter_level`.
    unsafe {
        jacobian_scatter(layout, l, columns, m, grad_jac, grad)
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!()
}

/// Checks what every vector loop relies on and returns the number of points `m`: the CPU and
/// the grid ([`usable`]), `per_point` values given for each point, rows that 32-bit gather
/// indices reach.
fn points(what: &str, layout: &Layout, columns: &[f32], per_point: usize, given: usize) -> usize {
    assert!(
        usable(layout.features),
        "{what}: the vector hash-grid loops need AVX-512 F and 2 features"
    );
    let m = columns.len() / 3;
    assert!(
        given >= per_point * m,
        "{what}: {given} values for {m} points of {per_point}"
    );
    assert!(
        layout.total_rows() < i32::MAX as usize,
        "{what}: table rows beyond i32"
    );
    m
}

/// Checks that `table` holds every row's two features.
pub(super) fn table_covers(what: &str, layout: &Layout, table: &[f32]) {
    assert!(
        table.len() >= 2 * layout.total_rows(),
        "{what}: table of {} values",
        table.len()
    );
}

/// Checks that `grad` holds level `l`'s rows.
pub(super) fn level_covered(what: &str, layout: &Layout, l: usize, grad: &[f32]) {
    assert!(
        grad.len() >= 2 * layout.rows[l],
        "{what}: level gradient of {} values",
        grad.len()
    );
}

/// The feature pairs at `rows` (absolute): points 0–7's and points 8–15's, each `a, b` in turn.
///
/// # Safety
/// AVX-512 F, and every row below the table's rows.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn gather_pairs(rows: __m512i, pairs: *const f64) -> (__m512, __m512) {
    // SAFETY: the caller's promise.
    unsafe {
        (
            _mm512_castpd_ps(_mm512_i32gather_pd::<8>(
                _mm512_castsi512_si256(rows),
                pairs,
            )),
            _mm512_castpd_ps(_mm512_i32gather_pd::<8>(
                _mm512_extracti64x4_epi64::<1>(rows),
                pairs,
            )),
        )
    }
}

/// Level constants, broadcast.
#[cfg(target_arch = "x86_64")]
struct Level {
    scale: __m512,
    last_cell: __m512i,
    dense: bool,
    side: u32,
    side_v: __m512i,
    plane_v: __m512i,
    mask: __m512i,
}

#[cfg(target_arch = "x86_64")]
impl Level {
    #[target_feature(enable = "avx512f")]
    fn new(layout: &Layout, l: usize) -> Self {
        let n = layout.resolution[l];
        Self {
            scale: _mm512_set1_ps(n as f32),
            last_cell: _mm512_set1_epi32((n - 1) as i32),
            dense: layout.dense[l],
            side: n + 1,
            side_v: _mm512_set1_epi32((n + 1) as i32),
            plane_v: _mm512_set1_epi32(((n + 1) * (n + 1)) as i32),
            mask: _mm512_set1_epi32((layout.rows[l] - 1) as i32),
        }
    }

    /// The cells of points `i .. i + 16`: lower corners and fractions, as `Layout::cell`.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn cells(&self, columns: &[f32], m: usize, i: usize) -> ([__m512i; 3], [__m512; 3]) {
        let zero = _mm512_setzero_ps();
        let mut cell = [_mm512_setzero_si512(); 3];
        let mut f = [zero; 3];
        for k in 0..3 {
            // SAFETY: i + 16 ≤ m, and columns holds 3·m values.
            let p = unsafe { _mm512_loadu_ps(columns.as_ptr().add(k * m + i)) };
            let x = _mm512_mul_ps(
                _mm512_min_ps(_mm512_max_ps(p, zero), _mm512_set1_ps(1.0)),
                self.scale,
            );
            cell[k] = _mm512_min_epu32(_mm512_cvttps_epu32(x), self.last_cell);
            f[k] = _mm512_sub_ps(x, _mm512_cvtepu32_ps(cell[k]));
        }
        (cell, f)
    }

    /// The eight corner rows of `cell`, relative to the level, as `Layout::cell_rows`.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn rows(&self, cell: [__m512i; 3]) -> [__m512i; 8] {
        if self.dense {
            let base = _mm512_add_epi32(
                _mm512_add_epi32(cell[0], _mm512_mullo_epi32(cell[1], self.side_v)),
                _mm512_mullo_epi32(cell[2], self.plane_v),
            );
            let v = self.side;
            std::array::from_fn(|c| {
                let step =
                    (c & 1) as u32 + ((c >> 1) & 1) as u32 * v + ((c >> 2) & 1) as u32 * v * v;
                _mm512_add_epi32(base, _mm512_set1_epi32(step as i32))
            })
        } else {
            let one = _mm512_set1_epi32(1);
            let (py, pz) = (
                _mm512_set1_epi32(2_654_435_761_u32 as i32),
                _mm512_set1_epi32(805_459_861),
            );
            let hx = [cell[0], _mm512_add_epi32(cell[0], one)];
            let hy = [
                _mm512_mullo_epi32(cell[1], py),
                _mm512_mullo_epi32(_mm512_add_epi32(cell[1], one), py),
            ];
            let hz = [
                _mm512_mullo_epi32(cell[2], pz),
                _mm512_mullo_epi32(_mm512_add_epi32(cell[2], one), pz),
            ];
            std::array::from_fn(|c| {
                let h = _mm512_xor_si512(
                    _mm512_xor_si512(hx[c & 1], hy[(c >> 1) & 1]),
                    hz[(c >> 2) & 1],
                );
                _mm512_and_si512(h, self.mask)
            })
        }
    }

    /// The trilinear weights of fractions `f`: (x-factor · y-factor) · z-factor, the scalar
    /// loop's order.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn weights(f: [__m512; 3]) -> [__m512; 8] {
        let one = _mm512_set1_ps(1.0);
        let g = [
            _mm512_sub_ps(one, f[0]),
            _mm512_sub_ps(one, f[1]),
            _mm512_sub_ps(one, f[2]),
        ];
        let xy = [
            _mm512_mul_ps(g[0], g[1]),
            _mm512_mul_ps(f[0], g[1]),
            _mm512_mul_ps(g[0], f[1]),
            _mm512_mul_ps(f[0], f[1]),
        ];
        std::array::from_fn(|c| _mm512_mul_ps(xy[c & 3], if c >> 2 == 1 { f[2] } else { g[2] }))
    }

    /// The weights' derivatives along each axis, as `Layout::corners` computes them.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn slopes(&self, f: [__m512; 3]) -> [[__m512; 3]; 8] {
        let one = _mm512_set1_ps(1.0);
        let minus = _mm512_sub_ps(_mm512_setzero_ps(), self.scale);
        std::array::from_fn(|c| {
            let b = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let t: [__m512; 3] = std::array::from_fn(|k| {
                if b[k] == 1 {
                    f[k]
                } else {
                    _mm512_sub_ps(one, f[k])
                }
            });
            let s: [__m512; 3] =
                std::array::from_fn(|k| if b[k] == 1 { self.scale } else { minus });
            [
                _mm512_mul_ps(_mm512_mul_ps(s[0], t[1]), t[2]),
                _mm512_mul_ps(_mm512_mul_ps(t[0], s[1]), t[2]),
                _mm512_mul_ps(_mm512_mul_ps(t[0], t[1]), s[2]),
            ]
        })
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn encode(
    layout: &Layout,
    l: usize,
    table: &[f32],
    columns: &[f32],
    m: usize,
    dst: &mut [f32],
) -> usize {
    let level = Level::new(layout, l);
    let offset = _mm512_set1_epi32(layout.offset[l] as i32);
    // Each weight twice, for the two features of the pairs the gathers bring.
    let first8 = _mm512_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7);
    let last8 = _mm512_setr_epi32(8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13, 14, 14, 15, 15);
    let pairs = table.as_ptr() as *const f64;
    let full = m / LANES * LANES;
    for i in (0..full).step_by(LANES) {
        // SAFETY: see `encode_level`.
        let (cell, f) = unsafe { level.cells(columns, m, i) };
        let (rows, weights) = (level.rows(cell), Level::weights(f));
        let (mut lo, mut hi) = (_mm512_setzero_ps(), _mm512_setzero_ps());
        for c in 0..8 {
            let r = _mm512_add_epi32(rows[c], offset);
            // SAFETY: every row is below total_rows, the table holds 2 floats a row.
            let (tlo, thi) = unsafe { gather_pairs(r, pairs) };
            lo = _mm512_add_ps(
                lo,
                _mm512_mul_ps(_mm512_permutexvar_ps(first8, weights[c]), tlo),
            );
            hi = _mm512_add_ps(
                hi,
                _mm512_mul_ps(_mm512_permutexvar_ps(last8, weights[c]), thi),
            );
        }
        // SAFETY: dst holds 2·m floats and i + 16 ≤ m.
        unsafe {
            _mm512_storeu_ps(dst.as_mut_ptr().add(2 * i), lo);
            _mm512_storeu_ps(dst.as_mut_ptr().add(2 * i + LANES), hi);
        }
    }
    full
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn scatter(
    layout: &Layout,
    l: usize,
    columns: &[f32],
    m: usize,
    grad_level: &[f32],
    grad: &mut [f32],
) -> usize {
    let level = Level::new(layout, l);
    let full = m / LANES * LANES;
    let mut rows = [[0u32; LANES]; 8];
    let mut weights = [[0f32; LANES]; 8];
    for i in (0..full).step_by(LANES) {
        // SAFETY: see `scatter_level`.
        let (cell, f) = unsafe { level.cells(columns, m, i) };
        let (r, w) = (level.rows(cell), Level::weights(f));
        for c in 0..8 {
            // SAFETY: 16 lanes into arrays of 16.
            unsafe {
                _mm512_storeu_si512(rows[c].as_mut_ptr().cast(), r[c]);
                _mm512_storeu_ps(weights[c].as_mut_ptr(), w[c]);
            }
        }
        // The adds one point after another, as the scalar loop (rows repeat within a block).
        for j in 0..LANES {
            let (a, b) = (grad_level[2 * (i + j)], grad_level[2 * (i + j) + 1]);
            if a == 0.0 && b == 0.0 {
                continue;
            }
            for c in 0..8 {
                let (r, w) = (rows[c][j] as usize * 2, weights[c][j]);
                grad[r] += w * a;
                grad[r + 1] += w * b;
            }
        }
    }
    full
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn jacobian(
    layout: &Layout,
    table: &[f32],
    columns: &[f32],
    m: usize,
    jac: &mut [f32],
) -> usize {
    let levels: Vec<Level> = (0..layout.levels())
        .map(|l| Level::new(layout, l))
        .collect();
    let width = layout.levels() * 6;
    // Pairs (a, b) of 8 points each → the 16 a's and the 16 b's.
    let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
    let pairs = table.as_ptr() as *const f64;
    let mut block = [[0f32; LANES]; 6];
    let full = m / LANES * LANES;
    for i in (0..full).step_by(LANES) {
        for (l, level) in levels.iter().enumerate() {
            // SAFETY: see `jacobian_points`.
            let (cell, f) = unsafe { level.cells(columns, m, i) };
            let (rows, slopes) = (level.rows(cell), level.slopes(f));
            let offset = _mm512_set1_epi32(layout.offset[l] as i32);
            let mut acc = [_mm512_setzero_ps(); 6];
            for c in 0..8 {
                let r = _mm512_add_epi32(rows[c], offset);
                // SAFETY: every row is below total_rows.
                let (lo, hi) = unsafe { gather_pairs(r, pairs) };
                let feature = [
                    _mm512_permutex2var_ps(lo, even, hi),
                    _mm512_permutex2var_ps(lo, odd, hi),
                ];
                for (fi, t) in feature.iter().enumerate() {
                    for k in 0..3 {
                        let a = &mut acc[fi * 3 + k];
                        *a = _mm512_add_ps(*a, _mm512_mul_ps(slopes[c][k], *t));
                    }
                }
            }
            for (dst, a) in block.iter_mut().zip(acc) {
                // SAFETY: 16 lanes into an array of 16.
                unsafe { _mm512_storeu_ps(dst.as_mut_ptr(), a) };
            }
            for j in 0..LANES {
                let row = &mut jac[(i + j) * width + l * 6..(i + j) * width + l * 6 + 6];
                for (e, v) in row.iter_mut().enumerate() {
                    *v = block[e][j];
                }
            }
        }
    }
    full
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn jacobian_scatter(
    layout: &Layout,
    l: usize,
    columns: &[f32],
    m: usize,
    grad_jac: &[f32],
    grad: &mut [f32],
) -> usize {
    let level = Level::new(layout, l);
    let width = layout.levels() * 6;
    let (zero, one) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0));
    let mut rows = [[0u32; LANES]; 8];
    let mut slopes = [[[0f32; LANES]; 3]; 8];
    let full = m / LANES * LANES;
    for i in (0..full).step_by(LANES) {
        // SAFETY: see `jacobian_scatter_level`.
        let (cell, f) = unsafe { level.cells(columns, m, i) };
        let (r, s) = (level.rows(cell), level.slopes(f));
        // A clamped axis does not move the encoding: its slopes count as 0.
        let inside: [__m512; 3] = std::array::from_fn(|k| {
            // SAFETY: i + 16 ≤ m.
            let p = unsafe { _mm512_loadu_ps(columns.as_ptr().add(k * m + i)) };
            let within = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(p, zero)
                & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(p, one);
            _mm512_mask_blend_ps(within, zero, one)
        });
        for c in 0..8 {
            // SAFETY: 16 lanes into arrays of 16.
            unsafe {
                _mm512_storeu_si512(rows[c].as_mut_ptr().cast(), r[c]);
                for k in 0..3 {
                    _mm512_storeu_ps(slopes[c][k].as_mut_ptr(), _mm512_mul_ps(s[c][k], inside[k]));
                }
            }
        }
        for j in 0..LANES {
            let g = &grad_jac[(i + j) * width + l * 6..(i + j) * width + l * 6 + 6];
            for c in 0..8 {
                let r = rows[c][j] as usize * 2;
                for fi in 0..2 {
                    // `Iterator::sum`'s order: from -0.0, axis after axis.
                    let mut t = -0.0f32;
                    for k in 0..3 {
                        t += slopes[c][k][j] * g[fi * 3 + k];
                    }
                    grad[r + fi] += t;
                }
            }
        }
    }
    full
}
