//! NeuS's section weights as CubeCL kernels, one unit a ray walking its sections front to back.
//!
//! For a ray's SDF at its section ends `f_0 … f_S`, sharpness `s` and liveness `l` (1, or 0 for
//! padding): `P_k = σ(s f_k)`, the section's opacity
//! `α_k = l · clamp(ρ_k, 0, 1)` with `ρ_k = (P_k − P_{k+1} + ε) / (P_k + ε)`, `ε = 1e-5`, and its
//! weight `w_k = α_k T_k`, `T_k = exp(Σ_{j<k} log(1 + 1e-7 − α_j))`
//! ([`crate::render::sdf_volume`]'s definitions, rounding included).
//!
//! Backward, for the upstream gradient `g_k` and the forward's weights: `w_i` depends on `α_k` through `T_i` for `i > k`,
//! so `∂L/∂α_k = g_k T_k − (Σ_{i>k} g_i w_i) / (1 + 1e-7 − α_k)`; the clamp passes it where
//! `0 ≤ ρ_k ≤ 1` (as Burn's clamp does); `∂ρ_k/∂P_k = P_{k+1} / (P_k + ε)²`,
//! `∂ρ_k/∂P_{k+1} = −1 / (P_k + ε)`, `∂P/∂f = s P (1 − P)` and `∂P/∂s = f P (1 − P)`. The
//! sharpness's gradient is summed over the ray's sections into one value a ray.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use crate::kernels::cube_launch::{assert_f32, empty_like, grid};

/// `ε` of the opacity's ratio.
const EPS: f32 = 1e-5;

/// `1 + 1e-7`: what the clear share's logarithm is taken of, less the opacity.
const CLEAR: f32 = 1.0 + 1e-7;

/// `σ(x) = 1 / (1 + e^(−x))`.
#[cube]
fn logistic(x: f32) -> f32 {
    1.0 / (1.0 + f32::exp(-x))
}

/// Section `k`'s opacity and the clamp's pass (1 inside `[0, 1]`, else 0).
#[cube]
fn opacity(p: f32, next: f32, live: f32) -> (f32, f32) {
    let ratio = (p - next + EPS) / (p + EPS);
    let mut pass = 1.0f32;
    if ratio < 0.0 {
        pass = 0.0;
    }
    if ratio > 1.0 {
        pass = 0.0;
    }
    (f32::clamp(ratio, 0.0, 1.0) * live, pass)
}

/// Ray `r`'s weights (`out[r, ..]`) from its SDF at its section ends.
#[cube(launch)]
fn forward_kernel(
    ends: &[f32],
    live: &[f32],
    sharpness: &[f32],
    out: &mut [f32],
    #[comptime] sections: usize,
) {
    let rays = live.len();
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let s = sharpness[0];
    let (row, out_row) = (r * (sections + 1), r * sections);
    let mut p = logistic(s * ends[row]);
    let mut log_clear = 0.0f32;
    for k in 0..sections {
        let next = logistic(s * ends[row + k + 1]);
        let (alpha, _pass) = opacity(p, next, live[r]);
        out[out_row + k] = alpha * f32::exp(log_clear);
        log_clear += f32::ln(CLEAR - alpha);
        p = next;
    }
}

/// Ray `r`'s `∂L/∂f` (`grad_ends[r, ..]`) and its share of `∂L/∂s` (`grad_sharpness[r]`) for
/// the upstream gradient `grad [R, S]`.
#[cube(launch)]
fn backward_kernel(
    ends: &[f32],
    live: &[f32],
    sharpness: &[f32],
    weights: &[f32],
    grad: &[f32],
    grad_ends: &mut [f32],
    grad_sharpness: &mut [f32],
    #[comptime] sections: usize,
) {
    let rays = live.len();
    if ABSOLUTE_POS >= rays {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let s = sharpness[0];
    let (row, out_row) = (r * (sections + 1), r * sections);
    // Σ g_i w_i over the ray, from the forward's weights.
    let mut total = 0.0f32;
    for k in 0..sections {
        total += grad[out_row + k] * weights[out_row + k];
    }
    // Each section's gradient, `Σ_{i>k} g_i w_i` as the total less the prefix.
    let mut f = ends[row];
    let mut p = logistic(s * f);
    let mut log_clear = 0.0f32;
    let mut prefix = 0.0f32;
    let mut carried = 0.0f32; // ∂L/∂P_k from section k − 1
    let mut ray_s = 0.0f32;
    for k in 0..sections {
        let f_next = ends[row + k + 1];
        let next = logistic(s * f_next);
        let (alpha, pass) = opacity(p, next, live[r]);
        let through = f32::exp(log_clear);
        let g = grad[out_row + k];
        prefix += g * weights[out_row + k];
        let grad_alpha = g * through - (total - prefix) / (CLEAR - alpha);
        let grad_ratio = grad_alpha * live[r] * pass;
        let grad_p = carried + grad_ratio * next / ((p + EPS) * (p + EPS));
        let slope = p * (1.0 - p);
        grad_ends[row + k] = grad_p * s * slope;
        ray_s += grad_p * f * slope;
        carried = -grad_ratio / (p + EPS);
        log_clear += f32::ln(CLEAR - alpha);
        p = next;
        f = f_next;
    }
    let slope = p * (1.0 - p);
    grad_ends[row + sections] = carried * s * slope;
    grad_sharpness[r] = ray_s + carried * f * slope;
}

/// The three inputs both kernels read, `[f, l, s]`, as contiguous f32.
fn inputs(ends: CubeTensor, live: CubeTensor, sharpness: CubeTensor) -> [CubeTensor; 3] {
    let tensors = [ends, live, sharpness];
    let named: Vec<_> = tensors
        .iter()
        .zip(["SDF", "liveness", "sharpness"])
        .collect();
    assert_f32("section weights", &named);
    tensors.map(into_contiguous)
}

/// `[R, S]`: the weights of the sections between `ends [R, S + 1]`, for rays live or not
/// (`live [R]`, 1 or 0) at sharpness `sharpness [1]`.
pub fn forward(ends: CubeTensor, live: CubeTensor, sharpness: CubeTensor) -> CubeTensor {
    let [rays, count] = [ends.meta.shape()[0], ends.meta.shape()[1]];
    let sections = count.saturating_sub(1);
    let out = empty_like(&ends, [rays, sections]);
    if rays == 0 || sections == 0 {
        return out;
    }
    let (client, (cubes, dim)) = (ends.client.clone(), grid(&ends, rays));
    let [ends, live, sharpness] = inputs(ends, live, sharpness).map(|x| x.into_buffer_arg());
    forward_kernel::launch(
        &client,
        cubes,
        dim,
        ends,
        live,
        sharpness,
        out.clone().into_buffer_arg(),
        sections,
    );
    out
}

/// `(∂L/∂f [R, S + 1], ∂L/∂s per ray [R])` for the upstream gradient `grad [R, S]` of
/// [`forward`], whose output `weights [R, S]` was.
pub fn backward(
    ends: CubeTensor,
    live: CubeTensor,
    sharpness: CubeTensor,
    weights: CubeTensor,
    grad: CubeTensor,
) -> (CubeTensor, CubeTensor) {
    let [rays, count] = [ends.meta.shape()[0], ends.meta.shape()[1]];
    let sections = count.saturating_sub(1);
    let grad_ends = empty_like(&ends, [rays, count]);
    let grad_sharpness = empty_like(&ends, [rays]);
    if rays == 0 || sections == 0 {
        return (grad_ends, grad_sharpness);
    }
    assert_f32(
        "section weights",
        &[(&weights, "weights"), (&grad, "upstream gradient")],
    );
    let (client, (cubes, dim)) = (ends.client.clone(), grid(&ends, rays));
    let [ends, live, sharpness] = inputs(ends, live, sharpness).map(|x| x.into_buffer_arg());
    backward_kernel::launch(
        &client,
        cubes,
        dim,
        ends,
        live,
        sharpness,
        into_contiguous(weights).into_buffer_arg(),
        into_contiguous(grad).into_buffer_arg(),
        grad_ends.clone().into_buffer_arg(),
        grad_sharpness.clone().into_buffer_arg(),
        sections,
    );
    (grad_ends, grad_sharpness)
}
