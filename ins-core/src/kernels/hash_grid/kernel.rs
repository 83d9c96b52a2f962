//! The multiresolution hash encoding (Müller et al. 2022) as plain Rust over slices: forward,
//! backward to the table and to the positions, and the spatial Jacobian with its backward.
//! The Burn op in [`super::op`] runs these on CPU backends; [`super::reference`] computes the
//! same numbers with ordinary Burn tensor ops, and tests hold the two together.
//!
//! Conventions (shared with the reference): positions are in `[0, 1]³` (clamped). Level `l` has
//! resolution `N_l = ⌊N_min · b^l⌋` with `b = (N_max / N_min)^(1/(L−1))`; its grid has
//! `N_l + 1` vertices per axis. Point `p` falls in the cell with lower corner
//! `i = min(⌊p·N_l⌋, N_l − 1)` at fraction `f = p·N_l − i`, and interpolates the 8 corner
//! vectors trilinearly. A level whose `(N_l + 1)³` vertices fit the table is stored densely
//! (`x + y·(N_l+1) + z·(N_l+1)²`); finer levels hash (`x ⊕ 2654435761·y ⊕ 805459861·z mod T`).

use super::vector;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Sizes of a hash grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct GridShape {
    /// Levels L.
    pub levels: u32,
    /// Features per level F.
    pub features: u32,
    /// log2 of the table size T per level.
    pub log2_table: u32,
    /// Coarsest resolution N_min.
    pub base_resolution: u32,
    /// Finest resolution N_max.
    pub max_resolution: u32,
}

/// Where each level lives in the table, and how it is indexed.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Resolution N_l of each level.
    pub resolution: Vec<u32>,
    /// First table row of each level.
    pub offset: Vec<usize>,
    /// Rows of each level (≤ T).
    pub rows: Vec<usize>,
    /// Whether a level is stored densely (else hashed).
    pub dense: Vec<bool>,
    /// Features per row.
    pub features: usize,
}

impl GridShape {
    /// The resolutions, offsets and storage of every level.
    pub fn layout(&self) -> Layout {
        let l = self.levels.max(1);
        let t = 1usize << self.log2_table;
        let growth = if l > 1 {
            ((self.max_resolution as f64).ln() - (self.base_resolution as f64).ln())
                / (l - 1) as f64
        } else {
            0.0
        };
        let mut out = Layout {
            resolution: Vec::new(),
            offset: Vec::new(),
            rows: Vec::new(),
            dense: Vec::new(),
            features: self.features as usize,
        };
        let mut offset = 0;
        for level in 0..l {
            // The small epsilon keeps exact powers (16·2^l) from flooring one below.
            let n = ((self.base_resolution as f64) * (growth * level as f64).exp() + 1e-9).floor()
                as u32;
            let n = n.max(1);
            let vertices = (n as usize + 1).pow(3);
            let dense = vertices <= t;
            let rows = if dense { vertices } else { t };
            out.resolution.push(n);
            out.offset.push(offset);
            out.rows.push(rows);
            out.dense.push(dense);
            offset += rows;
        }
        out
    }

    /// Width of the encoding: L·F.
    pub fn d_out(&self) -> usize {
        (self.levels * self.features) as usize
    }
}

impl Layout {
    /// Total rows of the table.
    pub fn total_rows(&self) -> usize {
        self.offset
            .last()
            .map_or(0, |o| o + self.rows.last().copied().unwrap_or(0))
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.resolution.len()
    }

    /// Row of vertex `(x, y, z)` in level `l` (absolute, offset included).
    #[inline]
    pub fn row(&self, l: usize, x: u32, y: u32, z: u32) -> usize {
        let local = if self.dense[l] {
            let n = self.resolution[l] as usize + 1;
            x as usize + y as usize * n + z as usize * n * n
        } else {
            let h = (x as u64)
                ^ (y as u64).wrapping_mul(2_654_435_761)
                ^ (z as u64).wrapping_mul(805_459_861);
            (h as usize) & (self.rows[l] - 1)
        };
        self.offset[l] + local
    }

    /// The cell of point `p` in level `l`: its lower corner and the fractions within it.
    #[inline(always)]
    fn cell(&self, l: usize, p: &[f32]) -> ([u32; 3], [f32; 3]) {
        let n = self.resolution[l];
        let nf = n as f32;
        let mut i = [0u32; 3];
        let mut f = [0f32; 3];
        for k in 0..3 {
            // Non-negative after the clamp, so truncation is the floor.
            let x = p[k].clamp(0.0, 1.0) * nf;
            let c = (x as u32).min(n - 1);
            i[k] = c;
            f[k] = x - c as f32;
        }
        (i, f)
    }

    /// The 8 corner rows of the cell with lower corner `i` in level `l` (corner `c` has
    /// offsets `(c & 1, c >> 1 & 1, c >> 2 & 1)`); the same rows as [`Layout::row`].
    #[inline(always)]
    fn cell_rows(&self, l: usize, i: [u32; 3]) -> [usize; 8] {
        let off = self.offset[l];
        let mut rows = [0usize; 8];
        if self.dense[l] {
            let v = self.resolution[l] as usize + 1;
            let base = i[0] as usize + i[1] as usize * v + i[2] as usize * v * v;
            for (c, r) in rows.iter_mut().enumerate() {
                *r = off + base + (c & 1) + ((c >> 1) & 1) * v + ((c >> 2) & 1) * v * v;
            }
        } else {
            // Only the low bits survive the mask, so 32-bit wrapping products give the same
            // rows as the 64-bit hash of `row`.
            let mask = (self.rows[l] - 1) as u32;
            let hx = [i[0], i[0] + 1];
            let hy = [
                i[1].wrapping_mul(2_654_435_761),
                (i[1] + 1).wrapping_mul(2_654_435_761),
            ];
            let hz = [
                i[2].wrapping_mul(805_459_861),
                (i[2] + 1).wrapping_mul(805_459_861),
            ];
            for (c, r) in rows.iter_mut().enumerate() {
                *r = off + ((hx[c & 1] ^ hy[(c >> 1) & 1] ^ hz[(c >> 2) & 1]) & mask) as usize;
            }
        }
        rows
    }

    /// The 8 corner rows and trilinear weights of point `p` in level `l` (corner `c` has
    /// offsets `(c & 1, c >> 1 & 1, c >> 2 & 1)`); the same rows as [`Layout::row`].
    #[inline(always)]
    pub fn corner_weights(&self, l: usize, p: &[f32]) -> ([usize; 8], [f32; 8]) {
        let (i, f) = self.cell(l, p);
        let g = [1.0 - f[0], 1.0 - f[1], 1.0 - f[2]];
        let mut w = [0f32; 8];
        for (c, wc) in w.iter_mut().enumerate() {
            *wc = (if c & 1 == 1 { f[0] } else { g[0] })
                * (if (c >> 1) & 1 == 1 { f[1] } else { g[1] })
                * (if (c >> 2) & 1 == 1 { f[2] } else { g[2] });
        }
        (self.cell_rows(l, i), w)
    }

    /// The 8 corner rows and trilinear weights of point `p` in level `l`, with the derivatives
    /// of the weights with respect to `p` (per axis).
    #[inline(always)]
    pub fn corners(&self, l: usize, p: [f32; 3]) -> ([usize; 8], [f32; 8], [[f32; 3]; 8]) {
        let nf = self.resolution[l] as f32;
        let (i, f) = self.cell(l, &p);
        let mut w = [0f32; 8];
        let mut dw = [[0f32; 3]; 8];
        for c in 0..8 {
            let b = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let t: [f32; 3] = std::array::from_fn(|k| if b[k] == 1 { f[k] } else { 1.0 - f[k] });
            let s: [f32; 3] = std::array::from_fn(|k| if b[k] == 1 { nf } else { -nf });
            w[c] = t[0] * t[1] * t[2];
            dw[c] = [s[0] * t[1] * t[2], t[0] * s[1] * t[2], t[0] * t[1] * s[2]];
        }
        (self.cell_rows(l, i), w, dw)
    }
}

const CHUNK: usize = 1024;

/// Encodes `n` points (`positions`: `n·3`) into `out` (`n·L·F`, row major).
///
/// The lookups are random, so cache decides the speed: each thread takes a contiguous share of
/// the points and runs level by level over all of them, so one level's table stays in the
/// core's cache for a whole pass. Results go to a level-major scratch buffer (contiguous
/// writes) that is transposed into `out` at the end. Two-feature grids run 16 or 8 points at
/// a time through [`vector`] where the CPU has AVX-512 or AVX2.
pub fn forward(layout: &Layout, table: &[f32], positions: &[f32], out: &mut [f32]) {
    let (levels, nf) = (layout.levels(), layout.features);
    let n = positions.len() / 3;
    let mut scratch = vec![0f32; levels * n * nf];
    let share = n.div_ceil(rayon::current_num_threads().max(1)).max(CHUNK);
    // scratch[l][i] for the points of each share: split every level's block by share.
    level_parts(&mut scratch, n * nf, share * nf)
        .into_par_iter()
        .zip(positions.par_chunks(3 * share))
        .for_each(|(mut parts, pos)| {
            let columns = vector::loops(nf).map(|v| (v, vector::columns(pos)));
            for (l, dst) in parts.iter_mut().enumerate() {
                let done = columns
                    .as_ref()
                    .map_or(0, |(v, c)| (v.encode_level)(layout, l, table, c, dst));
                let rest = dst.chunks_exact_mut(nf).zip(pos.chunks_exact(3)).skip(done);
                for (d, p) in rest {
                    let (rows, w) = layout.corner_weights(l, p);
                    if nf == 2 {
                        let (mut a, mut b) = (0f32, 0f32);
                        for c in 0..8 {
                            let r = rows[c] * 2;
                            a += w[c] * table[r];
                            b += w[c] * table[r + 1];
                        }
                        d[0] = a;
                        d[1] = b;
                    } else {
                        d.fill(0.0);
                        for c in 0..8 {
                            let src = &table[rows[c] * nf..(rows[c] + 1) * nf];
                            for (x, s) in d.iter_mut().zip(src) {
                                *x += w[c] * s;
                            }
                        }
                    }
                }
            }
        });
    // Level-major scratch → point-major output.
    let width = levels * nf;
    out.par_chunks_mut(width * CHUNK)
        .enumerate()
        .for_each(|(ci, o)| match nf {
            2 => level_major_to_rows::<2>(&scratch, n, levels, ci * CHUNK, o),
            _ => {
                for (k, row) in o.chunks_exact_mut(width).enumerate() {
                    let i = ci * CHUNK + k;
                    for l in 0..levels {
                        let src = &scratch[(l * n + i) * nf..(l * n + i + 1) * nf];
                        row[l * nf..(l + 1) * nf].copy_from_slice(src);
                    }
                }
            }
        });
}

/// Level-major `blocks` (one of `block` values per level) cut into runs of `part` values: for
/// each run, its part of every level, so that a job can own one run of points at all levels.
fn level_parts(blocks: &mut [f32], block: usize, part: usize) -> Vec<Vec<&mut [f32]>> {
    let mut runs: Vec<Vec<&mut [f32]>> = (0..block.div_ceil(part.max(1)))
        .map(|_| Vec::new())
        .collect();
    for level in blocks.chunks_mut(block.max(1)) {
        for (r, p) in level.chunks_mut(part.max(1)).enumerate() {
            runs[r].push(p);
        }
    }
    runs
}

/// Copies the points `first..` of level-major `scratch` (`L × n × F`) into point-major `rows`
/// (`L·F` each). Why the constant `F`: a slice copy of a run-time length is a `memcpy` call
/// per point and level, 16 calls of 8 bytes a point, which took 8 % of a pretraining step.
#[allow(clippy::manual_memcpy)] // the loop of constant length is the point
fn level_major_to_rows<const F: usize>(
    scratch: &[f32],
    n: usize,
    levels: usize,
    first: usize,
    rows: &mut [f32],
) {
    for (k, row) in rows.chunks_exact_mut(levels * F).enumerate() {
        let i = first + k;
        for (l, dst) in row.chunks_exact_mut(F).enumerate() {
            let at = (l * n + i) * F;
            for f in 0..F {
                dst[f] = scratch[at + f];
            }
        }
    }
}

/// Copies point-major `rows` (`L·F` each) into their parts of the level-major blocks
/// `parts[l]` (`F` a point); the constant `F` as in [`level_major_to_rows`].
#[allow(clippy::manual_memcpy)] // as there
fn rows_to_levels<const F: usize>(rows: &[f32], parts: &mut [&mut [f32]]) {
    let levels = parts.len();
    for (k, g) in rows.chunks_exact(levels * F).enumerate() {
        for (l, part) in parts.iter_mut().enumerate() {
            for f in 0..F {
                part[k * F + f] = g[l * F + f];
            }
        }
    }
}

/// Splits the table into per-level slices so levels can be accumulated in parallel.
fn level_slices<'a>(layout: &Layout, table: &'a mut [f32]) -> Vec<&'a mut [f32]> {
    let nf = layout.features;
    let mut rest = table;
    let mut out = Vec::with_capacity(layout.levels());
    for l in 0..layout.levels() {
        let (head, tail) = rest.split_at_mut(layout.rows[l] * nf);
        out.push(head);
        rest = tail;
    }
    out
}

/// Adds `∂L/∂table` for upstream `grad_out` (`n·L·F`) into `grad_table` (zeroed by the caller).
///
/// The upstream gradient is first transposed to level-major order (one pass); then the levels,
/// which own disjoint rows, accumulate in parallel, each streaming its contiguous gradient
/// block while its table stays in cache.
pub fn backward_table(
    layout: &Layout,
    positions: &[f32],
    grad_out: &[f32],
    grad_table: &mut [f32],
) {
    let (levels, nf) = (layout.levels(), layout.features);
    let n = positions.len() / 3;
    let width = levels * nf;
    let mut by_level = vec![0f32; levels * n * nf];
    // One pass over the upstream rows, a chunk of points at a time, each writing its part of
    // every level's block: reading each level's columns out of all rows instead took a pass
    // over the whole gradient per level.
    level_parts(&mut by_level, n * nf, CHUNK * nf)
        .into_par_iter()
        .zip(grad_out.par_chunks(width * CHUNK))
        .for_each(|(mut parts, rows)| match nf {
            2 => rows_to_levels::<2>(rows, &mut parts),
            _ => {
                for (k, g) in rows.chunks_exact(width).enumerate() {
                    for (l, part) in parts.iter_mut().enumerate() {
                        part[k * nf..(k + 1) * nf].copy_from_slice(&g[l * nf..(l + 1) * nf]);
                    }
                }
            }
        });
    let columns = vector::loops(nf).map(|v| (v, vector::columns(positions)));
    level_slices(layout, grad_table)
        .into_par_iter()
        .zip(by_level.par_chunks(n * nf))
        .enumerate()
        .for_each(|(l, (g, go))| {
            let off = layout.offset[l];
            let done = columns
                .as_ref()
                .map_or(0, |(v, c)| (v.scatter_level)(layout, l, c, go, g));
            let rest = positions
                .chunks_exact(3)
                .zip(go.chunks_exact(nf))
                .skip(done);
            for (p, go) in rest {
                if go.iter().all(|v| *v == 0.0) {
                    continue;
                }
                let (rows, w) = layout.corner_weights(l, p);
                for c in 0..8 {
                    let dst = &mut g[(rows[c] - off) * nf..(rows[c] - off + 1) * nf];
                    for (d, s) in dst.iter_mut().zip(go) {
                        *d += w[c] * s;
                    }
                }
            }
        });
}

/// `∂L/∂positions` (`n·3`) for upstream `grad_out`.
pub fn backward_positions(
    layout: &Layout,
    table: &[f32],
    positions: &[f32],
    grad_out: &[f32],
    grad_positions: &mut [f32],
) {
    let (levels, nf) = (layout.levels(), layout.features);
    let width = levels * nf;
    grad_positions
        .par_chunks_mut(3 * CHUNK)
        .zip(positions.par_chunks(3 * CHUNK))
        .zip(grad_out.par_chunks(width * CHUNK))
        .for_each(|((gp, pos), go)| {
            for ((gp, p), go) in gp
                .chunks_exact_mut(3)
                .zip(pos.chunks_exact(3))
                .zip(go.chunks_exact(width))
            {
                let mut acc = [0f32; 3];
                let p = [p[0], p[1], p[2]];
                for l in 0..levels {
                    let (rows, _, dw) = layout.corners(l, p);
                    let go = &go[l * nf..(l + 1) * nf];
                    for c in 0..8 {
                        let src = &table[rows[c] * nf..(rows[c] + 1) * nf];
                        let dot: f32 = src.iter().zip(go).map(|(a, b)| a * b).sum();
                        for k in 0..3 {
                            acc[k] += dw[c][k] * dot;
                        }
                    }
                }
                // Clamped coordinates do not move the encoding.
                for k in 0..3 {
                    gp[k] = if (0.0..=1.0).contains(&p[k]) {
                        acc[k]
                    } else {
                        0.0
                    };
                }
            }
        });
}

/// The spatial Jacobian `∂out/∂p` into `jac` (`n·L·F·3`, the 3 axes last); two-feature grids
/// 16 or 8 points at a time through [`vector`] where the CPU has AVX-512 or AVX2.
pub fn jacobian(layout: &Layout, table: &[f32], positions: &[f32], jac: &mut [f32]) {
    let (levels, nf) = (layout.levels(), layout.features);
    let width = levels * nf * 3;
    jac.par_chunks_mut(width * CHUNK)
        .zip(positions.par_chunks(3 * CHUNK))
        .for_each(|(jac, pos)| {
            let done = vector::loops(nf).map_or(0, |v| {
                (v.jacobian_points)(layout, table, &vector::columns(pos), jac)
            });
            for (i, (j, p)) in jac
                .chunks_exact_mut(width)
                .zip(pos.chunks_exact(3))
                .enumerate()
            {
                let p = [p[0], p[1], p[2]];
                if i >= done {
                    j.fill(0.0);
                    for l in 0..levels {
                        let (rows, _, dw) = layout.corners(l, p);
                        for c in 0..8 {
                            let src = &table[rows[c] * nf..(rows[c] + 1) * nf];
                            for (fi, s) in src.iter().enumerate() {
                                for k in 0..3 {
                                    j[(l * nf + fi) * 3 + k] += dw[c][k] * s;
                                }
                            }
                        }
                    }
                }
                for k in 0..3 {
                    if !(0.0..=1.0).contains(&p[k]) {
                        for e in 0..levels * nf {
                            j[e * 3 + k] = 0.0;
                        }
                    }
                }
            }
        });
}

/// Adds `∂L/∂table` for upstream `grad_jac` (`n·L·F·3`) of [`jacobian`] into `grad_table`.
pub fn jacobian_backward_table(
    layout: &Layout,
    positions: &[f32],
    grad_jac: &[f32],
    grad_table: &mut [f32],
) {
    let (levels, nf) = (layout.levels(), layout.features);
    let width = levels * nf * 3;
    let columns = vector::loops(nf).map(|v| (v, vector::columns(positions)));
    level_slices(layout, grad_table)
        .into_par_iter()
        .enumerate()
        .for_each(|(l, g)| {
            let off = layout.offset[l];
            let done = columns.as_ref().map_or(0, |(v, c)| {
                (v.jacobian_scatter_level)(layout, l, c, grad_jac, g)
            });
            let rest = positions
                .chunks_exact(3)
                .zip(grad_jac.chunks_exact(width))
                .skip(done);
            for (p, gj) in rest {
                let p = [p[0], p[1], p[2]];
                let inside: [f32; 3] = std::array::from_fn(|k| {
                    if (0.0..=1.0).contains(&p[k]) {
                        1.0
                    } else {
                        0.0
                    }
                });
                let (rows, _, dw) = layout.corners(l, p);
                for c in 0..8 {
                    let dst = &mut g[(rows[c] - off) * nf..(rows[c] - off + 1) * nf];
                    for (fi, d) in dst.iter_mut().enumerate() {
                        let e = (l * nf + fi) * 3;
                        *d += (0..3)
                            .map(|k| dw[c][k] * inside[k] * gj[e + k])
                            .sum::<f32>();
                    }
                }
            }
        });
}

#[cfg(test)]
mod tests;
