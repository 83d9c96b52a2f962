//! The samplers as CubeCL kernels: stratified samples, a unit a sample; the inverse-CDF draws,
//! one unit a ray. Their jitter comes from [`crate::kernels::jitter`]'s counter, number
//! `r·n + i` of the seed's stream for sample `i` of ray `r`, as on the host.
//!
//! The draws: For ray `r` with samples
//! `t [S]` and weights `w [S]`, as [`crate::render::samplers::draw_from_weights`] defines them:
//! bin edges at the midpoints `m_j = (t_j + t_{j+1}) / 2` (`j < S − 1`), the pdf of the inner
//! weights `w_1 … w_{S−2}` (each plus 1e-5) over the bins between them, the CDF `c_0 = 0,
//! c_j = Σ_{k<j} pdf_k`; draw `i` at `u = clamp((i + ξ_i) / n, 0, 1 − 1e-6)` falls in the bin
//! `b = clamp(#{j : c_j ≤ u} − 1, 0, S − 3)` and lands at `m_b + (u − c_b) / (c_{b+1} − c_b)`
//! of the way to `m_{b+1}`. The `u` increase with `i`, so the count of edges below grows as
//! the draws go: one pass over the CDF serves them all.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use crate::kernels::cube_launch::{assert_f32, empty_like, grid};
use crate::kernels::jitter::{keys, uniform_in_kernel};

/// Ray `r`'s `draws` new distances (`out[r, ..]`); `cdf [R, samples − 1]` is the kernel's
/// scratch for the ray's CDF.
#[cube(launch)]
fn draw_kernel(
    t: &[f32],
    weights: &[f32],
    cdf: &mut [f32],
    out: &mut [f32],
    key_0: u32,
    key_1: u32,
    #[comptime] samples: usize,
    #[comptime] centred: bool,
) {
    let rays = t.len() / samples;
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let edges = cdf.len() / rays;
    let draws = out.len() / rays;
    let (row, edge_row) = (r * samples, r * edges);
    let mut total = 0.0f32;
    for k in 1..edges {
        total += weights[row + k] + 1e-5;
    }
    let mut running = 0.0f32;
    cdf[edge_row] = 0.0;
    for j in 1..edges {
        running += (weights[row + j] + 1e-5) / total;
        cdf[edge_row + j] = running;
    }
    // Edges at or below the current draw: never fewer than one, since c_0 = 0 ≤ u.
    let mut below = 0usize;
    for i in 0..draws {
        let mut jitter = 0.5f32;
        if !centred {
            jitter = uniform_in_kernel(key_0, key_1, u32::cast_from(r * draws + i));
        }
        let u = f32::clamp(
            (f32::cast_from(i) + jitter) / f32::cast_from(draws),
            0.0,
            1.0 - 1e-6,
        );
        loop {
            if below >= edges {
                break;
            }
            if cdf[edge_row + below] > u {
                break;
            }
            below += 1;
        }
        let mut b = edges - 2;
        if below == 0 {
            b = 0;
        } else if below - 1 < edges - 2 {
            b = below - 1;
        }
        let (c0, c1) = (cdf[edge_row + b], cdf[edge_row + b + 1]);
        let m0 = (t[row + b] + t[row + b + 1]) * 0.5;
        let m1 = (t[row + b + 1] + t[row + b + 2]) * 0.5;
        let frac = f32::clamp((u - c0) / f32::max(c1 - c0, 1e-8), 0.0, 1.0);
        out[r * draws + i] = m0 + frac * (m1 - m0);
    }
}

/// `[R, n]`: the draws of every ray of `t [R, S]` with weights `weights [R, S]`, jittered by
/// the stream of `seed` (`None`: at the bins' centres). Needs `S ≥ 3`: two bins at least.
pub fn draw(t: CubeTensor, weights: CubeTensor, draws: usize, seed: Option<u64>) -> CubeTensor {
    let [rays, samples] = [t.meta.shape()[0], t.meta.shape()[1]];
    assert!(
        samples >= 3,
        "drawing from weights needs three samples a ray, not {samples}"
    );
    assert_f32(
        "drawing from weights",
        &[(&t, "distances"), (&weights, "weights")],
    );
    let out = empty_like(&t, [rays, draws]);
    if rays == 0 || draws == 0 {
        return out;
    }
    let cdf = empty_like(&t, [rays, samples - 1]);
    let (count, dim) = grid(&t, rays);
    let [key_0, key_1] = keys(seed.unwrap_or(0));
    draw_kernel::launch(
        &t.client.clone(),
        count,
        dim,
        into_contiguous(t).into_buffer_arg(),
        into_contiguous(weights).into_buffer_arg(),
        cdf.into_buffer_arg(),
        out.clone().into_buffer_arg(),
        key_0,
        key_1,
        samples,
        seed.is_none(),
    );
    out
}

/// Sample `i` of ray `r` (`out[r, i]`, a unit each): `near + (far − near)·(i + u)/n`.
#[cube(launch)]
fn stratified_kernel(
    near: &[f32],
    far: &[f32],
    out: &mut [f32],
    key_0: u32,
    key_1: u32,
    #[comptime] samples: usize,
    #[comptime] centred: bool,
) {
    if ABSOLUTE_POS >= out.len() {
        terminate!();
    }
    let r = ABSOLUTE_POS / samples;
    let i = ABSOLUTE_POS % samples;
    let mut jitter = 0.5f32;
    if !centred {
        jitter = uniform_in_kernel(key_0, key_1, u32::cast_from(ABSOLUTE_POS));
    }
    let u = (f32::cast_from(i) + jitter) / f32::cast_from(samples);
    out[ABSOLUTE_POS] = near[r] + (far[r] - near[r]) * u;
}

/// `[R, n]`: `n` stratified samples between `near [R]` and `far [R]`, jittered by the stream of
/// `seed` (`None`: at the bins' centres).
pub fn stratified(
    near: CubeTensor,
    far: CubeTensor,
    samples: usize,
    seed: Option<u64>,
) -> CubeTensor {
    let rays = near.meta.shape()[0];
    assert_f32("stratified sampling", &[(&near, "near"), (&far, "far")]);
    let out = empty_like(&near, [rays, samples]);
    if rays == 0 || samples == 0 {
        return out;
    }
    let (count, dim) = grid(&near, rays * samples);
    let [key_0, key_1] = keys(seed.unwrap_or(0));
    stratified_kernel::launch(
        &near.client.clone(),
        count,
        dim,
        into_contiguous(near).into_buffer_arg(),
        into_contiguous(far).into_buffer_arg(),
        out.clone().into_buffer_arg(),
        key_0,
        key_1,
        samples,
        seed.is_none(),
    );
    out
}
