//! [`super::ragged`]'s compositing as CubeCL kernels, one unit a ray (of a style) walking its
//! own run of samples front to back: the forward, the backward (two walks: the weighted total,
//! then each sample's share) and the detached weights.
//!
//! Inputs: `sigma [S, N]`, `rgb [S, N, 3]`, `t [N]`, `delta [N]`, `offsets [R + 1]` (f32,
//! exact below 2²⁴) and `shading [4]` (the op's `settings`, a name the `cube` macro keeps): the
//! background's colour, then the transmittance below which a ray stops (0 walks every sample).
//! Rows `offsets[R]..N` (a bucket's padding) are read by no ray.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::ragged::OUTPUTS;
use crate::kernels::cube_launch::{assert_f32, contiguous_f32, empty_like, grid, zeros_like};

/// Unit `s·R + r`'s style `s`, ray `r`, and the rows of the ray's run, `start..end`.
#[cube]
fn run_of(offsets: &[f32], unit: usize) -> (usize, usize, usize, usize) {
    let rays = offsets.len() - 1;
    let r = unit % rays;
    let start = u32::cast_from(offsets[r]) as usize;
    let end = u32::cast_from(offsets[r + 1]) as usize;
    (unit / rays, r, start, end)
}

/// Ray `r` of style `s` (unit `s·R + r`): its colour, depth and opacity in `out[unit, 0..5]`.
#[cube(launch)]
fn forward_kernel(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    offsets: &[f32],
    shading: &[f32],
    out: &mut [f32],
) {
    let units = out.len() / 5;
    if ABSOLUTE_POS >= units {
        terminate!();
    }
    let n = t.len();
    let (style, _, start, end) = run_of(offsets, ABSOLUTE_POS);
    let stop_below = shading[3];
    let mut clear = 1.0f32;
    let mut red = 0.0f32;
    let mut green = 0.0f32;
    let mut blue = 0.0f32;
    let mut depth = 0.0f32;
    let mut opacity = 0.0f32;
    for k in start..end {
        if clear < stop_below {
            break;
        }
        let i = style * n + k;
        let through = f32::exp(-(sigma[i] * delta[k]));
        let w = clear * (1.0 - through);
        clear *= through;
        red += w * rgb[i * 3];
        green += w * rgb[i * 3 + 1];
        blue += w * rgb[i * 3 + 2];
        depth += w * t[k];
        opacity += w;
    }
    let rest = 1.0 - opacity;
    let o = ABSOLUTE_POS * 5;
    out[o] = red + rest * shading[0];
    out[o + 1] = green + rest * shading[1];
    out[o + 2] = blue + rest * shading[2];
    out[o + 3] = depth;
    out[o + 4] = opacity;
}

/// `∂L/∂σ` and `∂L/∂c` of ray `r` of style `s` for the upstream gradient `grad [S·R, 5]`, at
/// every row of its run (zeros behind the stop); the first and last ray of a style also zero
/// the rows no ray reads (a bucket's padding), so the outputs need no zeroing first.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn backward_kernel(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    offsets: &[f32],
    shading: &[f32],
    grad: &[f32],
    grad_sigma: &mut [f32],
    grad_rgb: &mut [f32],
) {
    let units = grad.len() / 5;
    if ABSOLUTE_POS >= units {
        terminate!();
    }
    let n = t.len();
    let (style, r, start, end) = run_of(offsets, ABSOLUTE_POS);
    let stop_below = shading[3];
    let o = ABSOLUTE_POS * 5;
    let (gr, gg, gb) = (grad[o], grad[o + 1], grad[o + 2]);
    let (gd, go) = (grad[o + 3], grad[o + 4]);
    // What a unit of weight is worth against the background, whatever the sample.
    let base = go - gr * shading[0] - gg * shading[1] - gb * shading[2];
    // First pass: Σ q_i w_i over the ray.
    let mut clear = 1.0f32;
    let mut total = 0.0f32;
    for k in start..end {
        if clear < stop_below {
            break;
        }
        let i = style * n + k;
        let through = f32::exp(-(sigma[i] * delta[k]));
        let w = clear * (1.0 - through);
        clear *= through;
        let q = base + gr * rgb[i * 3] + gg * rgb[i * 3 + 1] + gb * rgb[i * 3 + 2] + gd * t[k];
        total += q * w;
    }
    // Second pass: each sample's gradients, `Σ_{i>k} q_i w_i` as the total less the prefix;
    // zeros behind the stop.
    clear = 1.0f32;
    let mut prefix = 0.0f32;
    for k in start..end {
        let i = style * n + k;
        let mut g_sigma = 0.0f32;
        let mut w = 0.0f32;
        if clear >= stop_below {
            let through = f32::exp(-(sigma[i] * delta[k]));
            w = clear * (1.0 - through);
            let q = base + gr * rgb[i * 3] + gg * rgb[i * 3 + 1] + gb * rgb[i * 3 + 2] + gd * t[k];
            prefix += q * w;
            g_sigma = (q * clear * through - (total - prefix)) * delta[k];
            clear *= through;
        }
        grad_sigma[i] = g_sigma;
        grad_rgb[i * 3] = gr * w;
        grad_rgb[i * 3 + 1] = gg * w;
        grad_rgb[i * 3 + 2] = gb * w;
    }
    // The rows no ray reads (before the first, after the last): zeros, by the first and last
    // ray of each style.
    if r == 0 {
        for k in 0..start {
            zero_row(grad_sigma, grad_rgb, style * n + k);
        }
    }
    if r == offsets.len() - 2 {
        for k in end..n {
            zero_row(grad_sigma, grad_rgb, style * n + k);
        }
    }
}

/// Sample `i`'s gradients zeroed.
#[cube]
fn zero_row(grad_sigma: &mut [f32], grad_rgb: &mut [f32], i: usize) {
    grad_sigma[i] = 0.0;
    grad_rgb[i * 3] = 0.0;
    grad_rgb[i * 3 + 1] = 0.0;
    grad_rgb[i * 3 + 2] = 0.0;
}

/// Ray `r` of style `s`'s weights `T_k (1 − e^{−σ_k δ_k})` at its own rows of `out [S, N]`
/// (zeros behind the stop); the first and last ray of a style also zero the rows no ray reads.
#[cube(launch)]
#[allow(clippy::needless_range_loop)] // a kernel: CubeCL's loops are ranges
fn weights_kernel(sigma: &[f32], delta: &[f32], offsets: &[f32], shading: &[f32], out: &mut [f32]) {
    let rays = offsets.len() - 1;
    let n = delta.len();
    if ABSOLUTE_POS >= (out.len() / n) * rays {
        terminate!();
    }
    let (style, r, start, end) = run_of(offsets, ABSOLUTE_POS);
    let stop_below = shading[3];
    let mut clear = 1.0f32;
    for k in start..end {
        let i = style * n + k;
        let mut w = 0.0f32;
        if clear >= stop_below {
            let through = f32::exp(-(sigma[i] * delta[k]));
            w = clear * (1.0 - through);
            clear *= through;
        }
        out[i] = w;
    }
    if r == 0 {
        for k in 0..start {
            out[style * n + k] = 0.0;
        }
    }
    if r == rays - 1 {
        for k in end..n {
            out[style * n + k] = 0.0;
        }
    }
}

/// The six inputs both kernels read, contiguous f32.
fn inputs(tensors: [CubeTensor; 6]) -> [CubeTensor; 6] {
    let names = [
        "densities",
        "colours",
        "distances",
        "spacings",
        "ray offsets",
        "settings",
    ];
    contiguous_f32("compositing", tensors, names)
}

/// Per-sample outputs of `shapes` for the backward and weights kernels, which write every row:
/// allocated empty, with the units to launch (one a ray of a style), or zeros and no units where
/// there is no ray or no sample.
fn per_sample<const K: usize>(
    sigma: &CubeTensor,
    offsets: &CubeTensor,
    shapes: [Vec<usize>; K],
) -> (usize, [CubeTensor; K]) {
    let [styles, n] = [sigma.meta.shape()[0], sigma.meta.shape()[1]];
    let units = styles * (offsets.meta.shape()[0] - 1);
    if units == 0 || n == 0 {
        return (0, shapes.map(|shape| zeros_like(sigma, shape)));
    }
    (units, shapes.map(|shape| empty_like(sigma, shape)))
}

/// `[S·R, 5]`: each ray's colour (background included), depth and opacity, style-major.
pub fn forward(
    sigma: CubeTensor,
    rgb: CubeTensor,
    t: CubeTensor,
    delta: CubeTensor,
    offsets: CubeTensor,
    settings: CubeTensor,
) -> CubeTensor {
    let units = sigma.meta.shape()[0] * (offsets.meta.shape()[0] - 1);
    let out = empty_like(&sigma, [units, OUTPUTS]);
    if units == 0 {
        return out;
    }
    let (client, (count, dim)) = (sigma.client.clone(), grid(&sigma, units));
    let [sigma, rgb, t, delta, offsets, settings] =
        inputs([sigma, rgb, t, delta, offsets, settings]).map(|x| x.into_buffer_arg());
    forward_kernel::launch(
        &client,
        count,
        dim,
        sigma,
        rgb,
        t,
        delta,
        offsets,
        settings,
        out.clone().into_buffer_arg(),
    );
    out
}

/// `(∂L/∂σ [S, N], ∂L/∂c [S, N, 3])` for the upstream gradient `grad [S·R, 5]` of [`forward`].
pub fn backward(
    sigma: CubeTensor,
    rgb: CubeTensor,
    t: CubeTensor,
    delta: CubeTensor,
    offsets: CubeTensor,
    settings: CubeTensor,
    grad: CubeTensor,
) -> (CubeTensor, CubeTensor) {
    let [styles, n] = [sigma.meta.shape()[0], sigma.meta.shape()[1]];
    let (units, [grad_sigma, grad_rgb]) =
        per_sample(&sigma, &offsets, [vec![styles, n], vec![styles, n, 3]]);
    if units == 0 {
        return (grad_sigma, grad_rgb);
    }
    assert_f32("compositing", &[(&grad, "upstream gradient")]);
    let (client, (count, dim)) = (sigma.client.clone(), grid(&sigma, units));
    let [sigma, rgb, t, delta, offsets, settings] =
        inputs([sigma, rgb, t, delta, offsets, settings]).map(|x| x.into_buffer_arg());
    backward_kernel::launch(
        &client,
        count,
        dim,
        sigma,
        rgb,
        t,
        delta,
        offsets,
        settings,
        into_contiguous(grad).into_buffer_arg(),
        grad_sigma.clone().into_buffer_arg(),
        grad_rgb.clone().into_buffer_arg(),
    );
    (grad_sigma, grad_rgb)
}

/// `[S, N]`: each sample's weight under [`forward`]'s walk (0 behind a ray's stop and on rows
/// no ray reads).
pub fn weights(
    sigma: CubeTensor,
    delta: CubeTensor,
    offsets: CubeTensor,
    settings: CubeTensor,
) -> CubeTensor {
    let shape = sigma.meta.shape().to_vec();
    let (units, [out]) = per_sample(&sigma, &offsets, [shape]);
    if units == 0 {
        return out;
    }
    let named = [
        (&sigma, "densities"),
        (&delta, "spacings"),
        (&offsets, "ray offsets"),
        (&settings, "settings"),
    ];
    assert_f32("compositing weights", &named);
    let (client, (count, dim)) = (sigma.client.clone(), grid(&sigma, units));
    let [sigma, delta, offsets, settings] =
        [sigma, delta, offsets, settings].map(|x| into_contiguous(x).into_buffer_arg());
    weights_kernel::launch(
        &client,
        count,
        dim,
        sigma,
        delta,
        offsets,
        settings,
        out.clone().into_buffer_arg(),
    );
    out
}
