//! [`super::ragged`]'s compositing as CubeCL kernels: one unit a ray (of a style) walking its
//! own run of samples front to back, the gradients of [`super::cube`] without its padded rows.
//!
//! Inputs: `sigma [S, N]`, `rgb [S, N, 3]`, `t [N]`, `delta [N]`, `offsets [R + 1]` (f32,
//! exact below 2²⁴), `shading [4]` (called `settings` outside the kernels, a name the `cube` macro keeps) (the background's colour, then the transmittance below
//! which a ray stops: 0 walks every sample). Rows `offsets[R]..N` (a bucket's padding) are read
//! by no ray.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::zeros_client;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::cube::OUTPUTS;
use crate::kernels::cube_launch::{assert_f32, empty_like, grid};

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
    let rays = offsets.len() - 1;
    let n = t.len();
    let style = ABSOLUTE_POS / rays;
    let r = ABSOLUTE_POS % rays;
    let start = u32::cast_from(offsets[r]) as usize;
    let end = u32::cast_from(offsets[r + 1]) as usize;
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

/// `∂L/∂σ` and `∂L/∂c` of ray `r` of style `s` for the upstream gradient `grad [S·R, 5]`; the
/// outputs start zeroed (samples behind the stop, and the padding, keep 0).
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
    let rays = offsets.len() - 1;
    let n = t.len();
    let style = ABSOLUTE_POS / rays;
    let r = ABSOLUTE_POS % rays;
    let start = u32::cast_from(offsets[r]) as usize;
    let end = u32::cast_from(offsets[r + 1]) as usize;
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
    // Second pass: each sample's gradients, `Σ_{i>k} q_i w_i` as the total less the prefix.
    clear = 1.0f32;
    let mut prefix = 0.0f32;
    for k in start..end {
        if clear < stop_below {
            break;
        }
        let i = style * n + k;
        let through = f32::exp(-(sigma[i] * delta[k]));
        let w = clear * (1.0 - through);
        let q = base + gr * rgb[i * 3] + gg * rgb[i * 3 + 1] + gb * rgb[i * 3 + 2] + gd * t[k];
        prefix += q * w;
        grad_sigma[i] = (q * clear * through - (total - prefix)) * delta[k];
        grad_rgb[i * 3] = gr * w;
        grad_rgb[i * 3 + 1] = gg * w;
        grad_rgb[i * 3 + 2] = gb * w;
        clear *= through;
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
    let named: Vec<_> = tensors.iter().zip(names).collect();
    assert_f32("compositing", &named);
    tensors.map(into_contiguous)
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
    let units = styles * (offsets.meta.shape()[0] - 1);
    let zeros = |shape: Vec<usize>| {
        zeros_client(
            sigma.client.clone(),
            sigma.device.clone(),
            shape.into(),
            sigma.dtype,
        )
    };
    let (grad_sigma, grad_rgb) = (zeros(vec![styles, n]), zeros(vec![styles, n, 3]));
    if units == 0 || n == 0 {
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
