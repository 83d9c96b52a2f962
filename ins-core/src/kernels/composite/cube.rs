//! Compositing as CubeCL kernels: one unit per ray walks its samples front to back, as
//! instant-ngp and nerfacc do. The forward keeps the running optical depth `Σ_{j<i} τ_j`; the
//! backward walks the ray twice, first for `Σ_i q_i w_i` (what every sample's weight is worth to
//! the loss), then for each sample's gradient.
//!
//! With `τ_i = σ_i δ_i`, `T_i = exp(−Σ_{j<i} τ_j)`, `w_i = T_i (1 − e^{−τ_i})` and the outputs
//! `C = Σ w_i c_i + (1 − O)·bg`, `D = Σ w_i t_i`, `O = Σ w_i`, an upstream gradient
//! `(g_C, g_D, g_O)` gives `∂L/∂w_i = q_i = g_C·(c_i − bg) + g_D t_i + g_O`, so
//! `∂L/∂c_i = g_C w_i` and, since `w_i` depends on `τ_k` through `T_i` for `i > k`,
//! `∂L/∂τ_k = q_k T_k e^{−τ_k} − Σ_{i>k} q_i w_i`, and `∂L/∂σ_k = δ_k ∂L/∂τ_k`.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use crate::kernels::cube_launch::{assert_f32, empty_like, grid};

/// The outputs a ray gets: colour (3), depth, opacity.
pub const OUTPUTS: usize = 5;

/// Ray `r`'s colour, depth and opacity (`out[r, 0..5]`) from its `s` samples.
#[cube(launch)]
fn forward_kernel(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    background: &[f32],
    out: &mut [f32],
) {
    let rays = out.len() / 5;
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let s = sigma.len() / rays;
    let mut depth_in_front = 0.0f32;
    let mut red = 0.0f32;
    let mut green = 0.0f32;
    let mut blue = 0.0f32;
    let mut depth = 0.0f32;
    let mut opacity = 0.0f32;
    for k in 0..s {
        let i = r * s + k;
        let tau = sigma[i] * delta[i];
        let w = f32::exp(-depth_in_front) * (1.0 - f32::exp(-tau));
        depth_in_front += tau;
        red += w * rgb[i * 3];
        green += w * rgb[i * 3 + 1];
        blue += w * rgb[i * 3 + 2];
        depth += w * t[i];
        opacity += w;
    }
    let rest = 1.0 - opacity;
    out[r * 5] = red + rest * background[0];
    out[r * 5 + 1] = green + rest * background[1];
    out[r * 5 + 2] = blue + rest * background[2];
    out[r * 5 + 3] = depth;
    out[r * 5 + 4] = opacity;
}

/// Ray `r`'s compositing weights `w_i = T_i (1 − e^{−τ_i})` (`out[r, ..]`), what the
/// hierarchical sampler draws from.
#[cube(launch)]
fn weights_kernel(sigma: &[f32], delta: &[f32], out: &mut [f32], #[comptime] samples: usize) {
    let rays = sigma.len() / samples;
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let mut depth_in_front = 0.0f32;
    for k in 0..samples {
        let i = r * samples + k;
        let tau = sigma[i] * delta[i];
        out[i] = f32::exp(-depth_in_front) * (1.0 - f32::exp(-tau));
        depth_in_front += tau;
    }
}

/// `∂L/∂σ [R, S]` and `∂L/∂c [R, S, 3]` of ray `r` for the upstream gradient `grad [R, 5]`.
#[cube(launch)]
fn backward_kernel(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    background: &[f32],
    grad: &[f32],
    grad_sigma: &mut [f32],
    grad_rgb: &mut [f32],
) {
    let rays = grad.len() / 5;
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let s = sigma.len() / rays;
    let (gr, gg, gb) = (grad[r * 5], grad[r * 5 + 1], grad[r * 5 + 2]);
    let (gd, go) = (grad[r * 5 + 3], grad[r * 5 + 4]);
    // What a unit of weight is worth against the background, whatever the sample.
    let base = go - gr * background[0] - gg * background[1] - gb * background[2];
    // First pass: Σ q_i w_i over the ray.
    let mut depth_in_front = 0.0f32;
    let mut total = 0.0f32;
    for k in 0..s {
        let i = r * s + k;
        let tau = sigma[i] * delta[i];
        let w = f32::exp(-depth_in_front) * (1.0 - f32::exp(-tau));
        depth_in_front += tau;
        let q = base + gr * rgb[i * 3] + gg * rgb[i * 3 + 1] + gb * rgb[i * 3 + 2] + gd * t[i];
        total += q * w;
    }
    // Second pass: each sample's gradients, `Σ_{i>k} q_i w_i` as the total less the prefix.
    depth_in_front = 0.0f32;
    let mut prefix = 0.0f32;
    for k in 0..s {
        let i = r * s + k;
        let tau = sigma[i] * delta[i];
        let in_front = f32::exp(-depth_in_front);
        let through = f32::exp(-tau);
        let w = in_front * (1.0 - through);
        depth_in_front += tau;
        let q = base + gr * rgb[i * 3] + gg * rgb[i * 3 + 1] + gb * rgb[i * 3 + 2] + gd * t[i];
        prefix += q * w;
        grad_sigma[i] = (q * in_front * through - (total - prefix)) * delta[i];
        grad_rgb[i * 3] = gr * w;
        grad_rgb[i * 3 + 1] = gg * w;
        grad_rgb[i * 3 + 2] = gb * w;
    }
}

/// The five inputs both kernels read, `[σ, c, t, δ, background]`, as contiguous f32.
fn inputs(
    sigma: CubeTensor,
    rgb: CubeTensor,
    t: CubeTensor,
    delta: CubeTensor,
    background: CubeTensor,
) -> [CubeTensor; 5] {
    let names = [
        "densities",
        "colours",
        "distances",
        "spacings",
        "background",
    ];
    let tensors = [sigma, rgb, t, delta, background];
    let named: Vec<_> = tensors.iter().zip(names).collect();
    assert_f32("compositing", &named);
    tensors.map(into_contiguous)
}

/// `[R, 5]`: each ray's colour (background included), depth and opacity.
pub fn forward(
    sigma: CubeTensor,
    rgb: CubeTensor,
    t: CubeTensor,
    delta: CubeTensor,
    background: CubeTensor,
) -> CubeTensor {
    let rays = sigma.meta.shape()[0];
    let out = empty_like(&sigma, [rays, OUTPUTS]);
    if rays == 0 {
        return out;
    }
    let (client, (count, dim)) = (sigma.client.clone(), grid(&sigma, rays));
    let [sigma, rgb, t, delta, background] =
        inputs(sigma, rgb, t, delta, background).map(|x| x.into_buffer_arg());
    let output = out.clone().into_buffer_arg();
    forward_kernel::launch(
        &client, count, dim, sigma, rgb, t, delta, background, output,
    );
    out
}

/// `(∂L/∂σ [R, S], ∂L/∂c [R, S, 3])` for the upstream gradient `grad [R, 5]` of [`forward`].
pub fn backward(
    sigma: CubeTensor,
    rgb: CubeTensor,
    t: CubeTensor,
    delta: CubeTensor,
    background: CubeTensor,
    grad: CubeTensor,
) -> (CubeTensor, CubeTensor) {
    let [rays, samples] = [sigma.meta.shape()[0], sigma.meta.shape()[1]];
    let grad_sigma = empty_like(&sigma, [rays, samples]);
    let grad_rgb = empty_like(&sigma, [rays, samples, 3]);
    if rays == 0 || samples == 0 {
        return (grad_sigma, grad_rgb);
    }
    assert_f32("compositing", &[(&grad, "upstream gradient")]);
    let (client, (count, dim)) = (sigma.client.clone(), grid(&sigma, rays));
    let [sigma, rgb, t, delta, background] =
        inputs(sigma, rgb, t, delta, background).map(|x| x.into_buffer_arg());
    backward_kernel::launch(
        &client,
        count,
        dim,
        sigma,
        rgb,
        t,
        delta,
        background,
        into_contiguous(grad).into_buffer_arg(),
        grad_sigma.clone().into_buffer_arg(),
        grad_rgb.clone().into_buffer_arg(),
    );
    (grad_sigma, grad_rgb)
}

/// `[R, S]`: the weights of every sample under densities `sigma [R, S]` and spacings
/// `delta [R, S]`, as [`forward`] weighs them.
pub fn weights(sigma: CubeTensor, delta: CubeTensor) -> CubeTensor {
    let [rays, samples] = [sigma.meta.shape()[0], sigma.meta.shape()[1]];
    let out = empty_like(&sigma, [rays, samples]);
    if rays == 0 || samples == 0 {
        return out;
    }
    assert_f32(
        "compositing",
        &[(&sigma, "densities"), (&delta, "spacings")],
    );
    let (client, (count, dim)) = (sigma.client.clone(), grid(&sigma, rays));
    weights_kernel::launch(
        &client,
        count,
        dim,
        into_contiguous(sigma).into_buffer_arg(),
        into_contiguous(delta).into_buffer_arg(),
        out.clone().into_buffer_arg(),
        samples,
    );
    out
}
