//! The hash encoding's hottest loops eight points at a time with AVX2: [`super::avx512`]'s
//! loops for CPUs without AVX-512 (AMD before Zen 4, most laptop and desktop Intel CPUs), for
//! grids of two features a level.
//!
//! On such a CPU (AMD EPYC Zen 3) the one-point-at-a-time loops were 58 % of an IDR volume
//! step: the lookup 14 %, the spatial Jacobian 14 %, its table gradient 23 %, the lookup's table
//! gradient 8 %. As in `avx512`, the cell, the eight weights (or their slopes) and the eight rows
//! are computed in vector registers, here for 8 points; each corner's two features come from
//! one 64-bit load a point (see `gather_features`); the gradients' adds stay one point after
//! another. The arithmetic is the scalar loops' (`super::kernel`), operation for operation, so
//! results are bit-identical.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::avx512::{level_covered, table_covers};
use super::kernel::Layout;

/// Points a call handles together.
pub const LANES: usize = 8;

/// Whether the vector loops can run: an x86-64 CPU with AVX2, and two features a level.
pub fn usable(features: usize) -> bool {
    features == 2 && cpu_has_avx2()
}

#[cfg(target_arch = "x86_64")]
fn cpu_has_avx2() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| is_x86_feature_detected!("avx2"))
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_has_avx2() -> bool {
    false
}

/// Level `l`'s features of the first `8·⌊m/8⌋` points of `columns` (from
/// [`super::avx512::columns`], `m` points) into `dst` (`m·2`, point-major); returns how many
/// points it wrote.
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
    // SAFETY: AVX2 is present (`usable`), and the slices are as long as checked above; every
    // row the loads read is below `total_rows` (the level's rows are masked or bounded by its
    // resolution, as in the scalar loop).
    unsafe {
        encode(layout, l, table, columns, m, dst)
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!()
}

/// Adds level `l`'s table gradient for the first `8·⌊m/8⌋` points (`grad_level`: their upstream
/// gradient of this level, `m·2`) into `grad` (the level's own rows, `rows·2`), in the scalar
/// loop's order; returns how many points it took.
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

/// The spatial Jacobian rows (`L·2·3` each, the axes last) of the first `8·⌊m/8⌋` points of
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
/// of `L·2·3`) for the first `8·⌊m/8⌋` points into `grad` (the level's own rows), in
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
/// the grid ([`usable`]), `per_point` values given for each point, and feature indices
/// (`2 · row + 1`) within `i32`, as the rows are computed in 32-bit lanes.
fn points(what: &str, layout: &Layout, columns: &[f32], per_point: usize, given: usize) -> usize {
    assert!(
        usable(layout.features),
        "{what}: the AVX2 hash-grid loops need AVX2 and 2 features"
    );
    let m = columns.len() / 3;
    assert!(
        given >= per_point * m,
        "{what}: {given} values for {m} points of {per_point}"
    );
    assert!(
        2 * layout.total_rows() < i32::MAX as usize,
        "{what}: table entries beyond i32"
    );
    m
}

/// Level constants, broadcast.
#[cfg(target_arch = "x86_64")]
struct Level {
    scale: __m256,
    last_cell: __m256i,
    dense: bool,
    side: u32,
    side_v: __m256i,
    plane_v: __m256i,
    mask: __m256i,
}

#[cfg(target_arch = "x86_64")]
impl Level {
    #[target_feature(enable = "avx2")]
    fn new(layout: &Layout, l: usize) -> Self {
        let n = layout.resolution[l];
        Self {
            scale: _mm256_set1_ps(n as f32),
            last_cell: _mm256_set1_epi32((n - 1) as i32),
            dense: layout.dense[l],
            side: n + 1,
            side_v: _mm256_set1_epi32((n + 1) as i32),
            plane_v: _mm256_set1_epi32(((n + 1) * (n + 1)) as i32),
            mask: _mm256_set1_epi32((layout.rows[l] - 1) as i32),
        }
    }

    /// The cells of points `i .. i + 8`: lower corners and fractions, as `Layout::cell`. (The
    /// signed conversions are the unsigned ones of `avx512` here: every value lies in
    /// `[0, resolution]`, far below 2³¹.)
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn cells(&self, columns: &[f32], m: usize, i: usize) -> ([__m256i; 3], [__m256; 3]) {
        let zero = _mm256_setzero_ps();
        let mut cell = [_mm256_setzero_si256(); 3];
        let mut f = [zero; 3];
        for k in 0..3 {
            // SAFETY: i + 8 ≤ m, and columns holds 3·m values.
            let p = unsafe { _mm256_loadu_ps(columns.as_ptr().add(k * m + i)) };
            let x = _mm256_mul_ps(
                _mm256_min_ps(_mm256_max_ps(p, zero), _mm256_set1_ps(1.0)),
                self.scale,
            );
            cell[k] = _mm256_min_epu32(_mm256_cvttps_epi32(x), self.last_cell);
            f[k] = _mm256_sub_ps(x, _mm256_cvtepi32_ps(cell[k]));
        }
        (cell, f)
    }

    /// The eight corner rows of `cell`, relative to the level, as `Layout::cell_rows`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn rows(&self, cell: [__m256i; 3]) -> [__m256i; 8] {
        if self.dense {
            let base = _mm256_add_epi32(
                _mm256_add_epi32(cell[0], _mm256_mullo_epi32(cell[1], self.side_v)),
                _mm256_mullo_epi32(cell[2], self.plane_v),
            );
            let v = self.side;
            std::array::from_fn(|c| {
                let step =
                    (c & 1) as u32 + ((c >> 1) & 1) as u32 * v + ((c >> 2) & 1) as u32 * v * v;
                _mm256_add_epi32(base, _mm256_set1_epi32(step as i32))
            })
        } else {
            let one = _mm256_set1_epi32(1);
            let (py, pz) = (
                _mm256_set1_epi32(2_654_435_761_u32 as i32),
                _mm256_set1_epi32(805_459_861),
            );
            let hx = [cell[0], _mm256_add_epi32(cell[0], one)];
            let hy = [
                _mm256_mullo_epi32(cell[1], py),
                _mm256_mullo_epi32(_mm256_add_epi32(cell[1], one), py),
            ];
            let hz = [
                _mm256_mullo_epi32(cell[2], pz),
                _mm256_mullo_epi32(_mm256_add_epi32(cell[2], one), pz),
            ];
            std::array::from_fn(|c| {
                let h = _mm256_xor_si256(
                    _mm256_xor_si256(hx[c & 1], hy[(c >> 1) & 1]),
                    hz[(c >> 2) & 1],
                );
                _mm256_and_si256(h, self.mask)
            })
        }
    }

    /// The trilinear weights of fractions `f`: (x-factor · y-factor) · z-factor, the scalar
    /// loop's order.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn weights(f: [__m256; 3]) -> [__m256; 8] {
        let one = _mm256_set1_ps(1.0);
        let g = [
            _mm256_sub_ps(one, f[0]),
            _mm256_sub_ps(one, f[1]),
            _mm256_sub_ps(one, f[2]),
        ];
        let xy = [
            _mm256_mul_ps(g[0], g[1]),
            _mm256_mul_ps(f[0], g[1]),
            _mm256_mul_ps(g[0], f[1]),
            _mm256_mul_ps(f[0], f[1]),
        ];
        std::array::from_fn(|c| _mm256_mul_ps(xy[c & 3], if c >> 2 == 1 { f[2] } else { g[2] }))
    }

    /// The weights' derivatives along each axis, as `Layout::corners` computes them.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn slopes(&self, f: [__m256; 3]) -> [[__m256; 3]; 8] {
        let one = _mm256_set1_ps(1.0);
        let minus = _mm256_sub_ps(_mm256_setzero_ps(), self.scale);
        std::array::from_fn(|c| {
            let b = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let t: [__m256; 3] = std::array::from_fn(|k| {
                if b[k] == 1 {
                    f[k]
                } else {
                    _mm256_sub_ps(one, f[k])
                }
            });
            let s: [__m256; 3] =
                std::array::from_fn(|k| if b[k] == 1 { self.scale } else { minus });
            [
                _mm256_mul_ps(_mm256_mul_ps(s[0], t[1]), t[2]),
                _mm256_mul_ps(_mm256_mul_ps(t[0], s[1]), t[2]),
                _mm256_mul_ps(_mm256_mul_ps(t[0], t[1]), s[2]),
            ]
        })
    }
}

/// The two features at absolute `rows` of 8 points: every first, every second.
///
/// A row's two features are adjacent, so each point's pair is one 64-bit load (8 loads, two
/// shuffles) instead of two 8-lane gathers (16 loads). It also keeps VSIB addressing out of
/// these loops: QEMU 7.2 (Debian 12's, which `cpu_fallback` runs them under) reads a gather
/// whose index is `ymm4` as if it had no index, so every lane loads the same row.
///
/// # Safety
/// AVX2, and every row below the table's rows.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn gather_features(rows: __m256i, table: *const f32) -> [__m256; 2] {
    let mut r = [0u32; LANES];
    // SAFETY: 8 lanes into an array of 8.
    unsafe { _mm256_storeu_si256(r.as_mut_ptr().cast(), rows) };
    // SAFETY: the caller's promise: `2·row + 1` is inside the table.
    let pair = |j: usize| unsafe { table.add(2 * r[j] as usize).cast::<f64>() };
    // SAFETY: as above (unaligned 64-bit loads).
    let (p01, p23, p45, p67) = unsafe {
        (
            _mm_loadh_pd(_mm_load_sd(pair(0)), pair(1)),
            _mm_loadh_pd(_mm_load_sd(pair(2)), pair(3)),
            _mm_loadh_pd(_mm_load_sd(pair(4)), pair(5)),
            _mm_loadh_pd(_mm_load_sd(pair(6)), pair(7)),
        )
    };
    // [a0 b0 a1 b1 | a4 b4 a5 b5] and [a2 b2 a3 b3 | a6 b6 a7 b7]: the firsts, the seconds.
    let x = _mm256_castpd_ps(_mm256_set_m128d(p45, p01));
    let y = _mm256_castpd_ps(_mm256_set_m128d(p67, p23));
    [
        _mm256_shuffle_ps::<0b10_00_10_00>(x, y),
        _mm256_shuffle_ps::<0b11_01_11_01>(x, y),
    ]
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn encode(
    layout: &Layout,
    l: usize,
    table: &[f32],
    columns: &[f32],
    m: usize,
    dst: &mut [f32],
) -> usize {
    let level = Level::new(layout, l);
    let offset = _mm256_set1_epi32(layout.offset[l] as i32);
    let full = m / LANES * LANES;
    for i in (0..full).step_by(LANES) {
        // SAFETY: see `encode_level`.
        let (cell, f) = unsafe { level.cells(columns, m, i) };
        let (rows, weights) = (level.rows(cell), Level::weights(f));
        let (mut a, mut b) = (_mm256_setzero_ps(), _mm256_setzero_ps());
        for c in 0..8 {
            let r = _mm256_add_epi32(rows[c], offset);
            // SAFETY: every row is below total_rows, the table holds 2 floats a row.
            let [ta, tb] = unsafe { gather_features(r, table.as_ptr()) };
            a = _mm256_add_ps(a, _mm256_mul_ps(weights[c], ta));
            b = _mm256_add_ps(b, _mm256_mul_ps(weights[c], tb));
        }
        // Interleaved back into pairs: points 0, 1, 4, 5 and 2, 3, 6, 7, then in order.
        let (lo, hi) = (_mm256_unpacklo_ps(a, b), _mm256_unpackhi_ps(a, b));
        // SAFETY: dst holds 2·m floats and i + 8 ≤ m.
        unsafe {
            _mm256_storeu_ps(
                dst.as_mut_ptr().add(2 * i),
                _mm256_permute2f128_ps::<0x20>(lo, hi),
            );
            _mm256_storeu_ps(
                dst.as_mut_ptr().add(2 * i + LANES),
                _mm256_permute2f128_ps::<0x31>(lo, hi),
            );
        }
    }
    full
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
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
            // SAFETY: 8 lanes into arrays of 8.
            unsafe {
                _mm256_storeu_si256(rows[c].as_mut_ptr().cast(), r[c]);
                _mm256_storeu_ps(weights[c].as_mut_ptr(), w[c]);
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
#[target_feature(enable = "avx2")]
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
    let mut block = [[0f32; LANES]; 6];
    let full = m / LANES * LANES;
    for i in (0..full).step_by(LANES) {
        for (l, level) in levels.iter().enumerate() {
            // SAFETY: see `jacobian_points`.
            let (cell, f) = unsafe { level.cells(columns, m, i) };
            let (rows, slopes) = (level.rows(cell), level.slopes(f));
            let offset = _mm256_set1_epi32(layout.offset[l] as i32);
            let mut acc = [_mm256_setzero_ps(); 6];
            for c in 0..8 {
                let r = _mm256_add_epi32(rows[c], offset);
                // SAFETY: every row is below total_rows.
                let feature = unsafe { gather_features(r, table.as_ptr()) };
                for (fi, t) in feature.iter().enumerate() {
                    for k in 0..3 {
                        let a = &mut acc[fi * 3 + k];
                        *a = _mm256_add_ps(*a, _mm256_mul_ps(slopes[c][k], *t));
                    }
                }
            }
            for (dst, a) in block.iter_mut().zip(acc) {
                // SAFETY: 8 lanes into an array of 8.
                unsafe { _mm256_storeu_ps(dst.as_mut_ptr(), a) };
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
#[target_feature(enable = "avx2")]
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
    let (zero, one) = (_mm256_setzero_ps(), _mm256_set1_ps(1.0));
    let mut rows = [[0u32; LANES]; 8];
    let mut slopes = [[[0f32; LANES]; 3]; 8];
    let full = m / LANES * LANES;
    for i in (0..full).step_by(LANES) {
        // SAFETY: see `jacobian_scatter_level`.
        let (cell, f) = unsafe { level.cells(columns, m, i) };
        let (r, s) = (level.rows(cell), level.slopes(f));
        // A clamped axis does not move the encoding: its slopes count as 0.
        let inside: [__m256; 3] = std::array::from_fn(|k| {
            // SAFETY: i + 8 ≤ m.
            let p = unsafe { _mm256_loadu_ps(columns.as_ptr().add(k * m + i)) };
            let within = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(p, zero),
                _mm256_cmp_ps::<_CMP_LE_OQ>(p, one),
            );
            _mm256_and_ps(within, one)
        });
        for c in 0..8 {
            // SAFETY: 8 lanes into arrays of 8.
            unsafe {
                _mm256_storeu_si256(rows[c].as_mut_ptr().cast(), r[c]);
                for k in 0..3 {
                    _mm256_storeu_ps(slopes[c][k].as_mut_ptr(), _mm256_mul_ps(s[c][k], inside[k]));
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
