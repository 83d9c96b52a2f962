//! The inverse-CDF draws as a CubeCL kernel, one unit a ray. For ray `r` with samples
//! `t [S]` and weights `w [S]`, as [`crate::render::samplers::draw_from_weights`] defines them:
//! bin edges at the midpoints `m_j = (t_j + t_{j+1}) / 2` (`j < S − 1`), the pdf of the inner
//! weights `w_1 … w_{S−2}` (each plus 1e-5) over the bins between them, the CDF `c_0 = 0,
//! c_j = Σ_{k<j} pdf_k`; draw `i` at `u = clamp((i + ξ_i) / n, 0, 1 − 1e-6)` falls in the bin
//! `b = clamp(#{j : c_j ≤ u} − 1, 0, S − 3)` and lands at `m_b + (u − c_b) / (c_{b+1} − c_b)`
//! of the way to `m_{b+1}`. The `u` increase with `i`, so the count of edges below grows as
//! the draws go: one pass over the CDF serves them all.

use burn::backend::DType;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use crate::kernels::cube_launch::{empty_like, grid};

/// Ray `r`'s `draws` new distances (`out[r, ..]`); `cdf [R, samples − 1]` is the kernel's
/// scratch for the ray's CDF.
#[cube(launch)]
fn draw_kernel(
    t: &[f32],
    weights: &[f32],
    jitter: &[f32],
    cdf: &mut [f32],
    out: &mut [f32],
    #[comptime] samples: usize,
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
        let u = f32::clamp(
            (f32::cast_from(i) + jitter[r * draws + i]) / f32::cast_from(draws),
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

/// `[R, n]`: the draws of every ray of `t [R, S]` with weights `weights [R, S]` and jitter
/// `jitter [R, n]` in `[0, 1)` (0.5 for bin centres). Needs `S ≥ 3`: two bins at least.
pub fn draw(t: CubeTensor, weights: CubeTensor, jitter: CubeTensor) -> CubeTensor {
    let [rays, samples] = [t.meta.shape()[0], t.meta.shape()[1]];
    let draws = jitter.meta.shape()[1];
    assert!(
        samples >= 3,
        "drawing from weights needs three samples a ray, not {samples}"
    );
    let tensors = [t, weights, jitter];
    for (x, name) in tensors.iter().zip(["distances", "weights", "jitter"]) {
        assert_eq!(
            x.dtype,
            DType::F32,
            "drawing from weights runs in f32 ({name})"
        );
    }
    let [t, weights, jitter] = tensors.map(into_contiguous);
    let out = empty_like(&t, [rays, draws]);
    if rays == 0 || draws == 0 {
        return out;
    }
    let cdf = empty_like(&t, [rays, samples - 1]);
    let (count, dim) = grid(&t, rays);
    draw_kernel::launch(
        &t.client.clone(),
        count,
        dim,
        t.into_buffer_arg(),
        weights.into_buffer_arg(),
        jitter.into_buffer_arg(),
        cdf.into_buffer_arg(),
        out.clone().into_buffer_arg(),
        samples,
    );
    out
}
