//! Rendering rays of an IDR model: sphere-trace the SDF (no gradient), then, at the hits, IDR's
//! differentiable surface point `x(θ) = x₀ − v · f(x₀; θ) / (∇f(x₀) · v)` (∇f and v detached),
//! so colour gradients reach the SDF; shade with the normal ∇f(x(θ)) under every style.

use burn::prelude::*;
use ins_core::kernels::flex::is_flex;
use ins_core::render::gather::select_parallel;
use ins_core::render::sphere_tracing::device::sphere_trace_on_device;
use ins_core::render::sphere_tracing::{TraceOptions, Traced, sphere_trace};
use ins_core::shape_buckets::{pad_rows, padded_size};
use ins_scene::geometry::Vec3;
use ins_scene::rays::{Rays, flatten};

use super::model::IdrModel;
use ins_core::modules::sdf::SdfNet;

/// Signed distances at host points through a (non-autodiff) SDF network, in chunks.
pub fn sdf_at(sdf: &SdfNet, points: &[f32], device: &Device) -> Vec<f32> {
    let mut out = Vec::with_capacity(points.len() / 3);
    for chunk in points.chunks(3 * 65536) {
        let n = chunk.len() / 3;
        // Sphere tracing asks for fewer points every iteration: on GPUs a bucketed count (the
        // first point repeated) lets its kernels be reused.
        let rows = padded_size(n, device);
        let points: std::borrow::Cow<[f32]> = if rows == n {
            chunk.into()
        } else {
            let mut padded = chunk.to_vec();
            pad_rows(&mut padded, 3, rows);
            padded.into()
        };
        let x = Tensor::<1>::from_floats(&*points, device).reshape([rows, 3]);
        let mut f = sdf
            .sdf(x)
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap_or_else(|_| vec![f32::NAN; rows]);
        f.truncate(n);
        out.extend(f);
    }
    out
}

/// Traces rays against the model's current SDF (on the inner device, no gradient): on a CPU
/// by the host's tracer, which evaluates only the rays still marching; elsewhere with its
/// rounds on the device, four reads a trace instead of one a round.
pub fn trace(model: &IdrModel, rays: &Rays, opts: &TraceOptions, device: &Device) -> Traced {
    let sdf = model.sdf.valid();
    let inner = device.clone().inner();
    if is_flex(&inner) {
        sphere_trace(rays, opts, |p| sdf_at(&sdf, p, &inner))
    } else {
        sphere_trace_on_device(rays, opts, |x| sdf.sdf(x), &inner)
    }
}

/// IDR's differentiable surface point: `x(θ) = x₀ − v · f(x₀; θ) / (∇f(x₀) · v)` with `x₀`
/// (the traced hits `[H, 3]`), `v` (unit directions) and ∇f detached. Its value is `x₀` (where
/// f ≈ 0) and its derivative in θ is the implicit function's, `−v · (∂f/∂θ) / (∇f · v)`.
/// Only `f` is taped: the detached ∇f comes from the network without autodiff (its forward-mode
/// tangents would be computed and recorded for nothing).
pub fn surface_point(sdf: &SdfNet, x0: Tensor<2>, v: Tensor<2>) -> Tensor<2> {
    let [h, _] = x0.dims();
    let f0 = sdf.sdf(x0.clone());
    let g0 = if x0.device().is_autodiff() {
        let (_, _, g) = sdf.valid().forward_with_gradient(x0.clone().inner());
        Tensor::from_inner(g)
    } else {
        sdf.forward_with_gradient(x0.clone()).2
    };
    let denom = (g0 * v.clone()).sum_dim(1).reshape([h]);
    // Keep the step finite at grazing hits: |∇f · v| ≥ 0.01, sign kept (0 counts as +).
    let sign = denom
        .clone()
        .lower_elem(0.0)
        .float()
        .mul_scalar(-2.0)
        .add_scalar(1.0);
    let denom = (denom.abs().clamp_min(1e-2) * sign).reshape([h, 1]);
    x0 - v * (f0.reshape([h, 1]) / denom)
}

/// A render of `R` rays under `S` styles.
pub struct SurfaceRender {
    /// Colour `[S·R, 3]` (style-major), the background where a ray meets no surface.
    pub rgb: Tensor<2>,
    /// Where each ray met the surface.
    pub traced: Traced,
    /// Indices of the rays that hit.
    pub hits: Vec<usize>,
    /// The SDF gradient at the differentiable surface points `[H', 3]` (for eikonal terms):
    /// the first `hits.len()` rows are the hits, any further rows padding (GPU size buckets).
    pub surface_gradients: Option<Tensor<2>>,
    /// Wall time of the sphere tracing, in milliseconds (where a step's time goes).
    pub trace_ms: f64,
}

fn tensor2(v: Vec<f32>, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    Tensor::<1>::from_floats(v.as_slice(), device).reshape([rows, cols])
}

/// Renders `rays` (unit directions, unit-sphere intervals). With `differentiable`, hits go
/// through IDR's differentiable surface point (training); otherwise the traced point is shaded
/// directly (rendering, evaluation).
pub fn render_surface(
    model: &IdrModel,
    rays: &Rays,
    codes: Option<Tensor<2>>,
    background: [f32; 3],
    opts: &TraceOptions,
    differentiable: bool,
    device: &Device,
) -> SurfaceRender {
    let r = rays.len();
    let started = std::time::Instant::now();
    let traced = trace(model, rays, opts, device);
    let trace_ms = started.elapsed().as_secs_f64() * 1e3;
    let hits: Vec<usize> = (0..r).filter(|&i| traced.hit[i]).collect();
    let s = codes.as_ref().map_or(1, |c| c.dims()[0]);
    let bg = Tensor::<1>::from_floats(background, device)
        .reshape([1, 1, 3])
        .expand([s, 1, 3]);
    if hits.is_empty() {
        let rgb = bg.expand([s, r, 3]).reshape([s * r, 3]);
        return SurfaceRender {
            rgb,
            traced,
            hits,
            surface_gradients: None,
            trace_ms,
        };
    }
    // On GPUs the hits are padded to a bucketed count with copies of the first, read by no ray.
    let h = padded_size(hits.len(), device);
    let padded = || {
        hits.iter()
            .chain(std::iter::repeat_n(&hits[0], h - hits.len()))
    };
    let x0: Vec<f32> = padded()
        .flat_map(|&i| rays.point(i, traced.t[i]).to_array())
        .collect();
    let dirs: Vec<Vec3> = padded().map(|&i| rays.directions[i]).collect();
    let x0 = tensor2(x0, h, 3, device);
    let v = tensor2(flatten(&dirs), h, 3, device);
    let (x, normals, features) = if differentiable {
        let x = surface_point(&model.sdf, x0, v.clone());
        let (_, feat, g) = model.sdf.forward_with_gradient(x.clone());
        (x, g, feat)
    } else {
        let (_, feat, g) = model.sdf.forward_with_gradient(x0.clone());
        (x0, g, feat)
    };
    let colour = model.shade(x, normals.clone(), v, features, codes); // [S, H, 3]
    let mut index = vec![h as i64; r];
    for (k, &i) in hits.iter().enumerate() {
        index[i] = k as i64;
    }
    let index = Tensor::<1, Int>::from_data(TensorData::new(index, [r]), device);
    let rgb = select_parallel(Tensor::cat(vec![colour, bg], 1), 1, index).reshape([s * r, 3]);
    SurfaceRender {
        rgb,
        traced,
        hits,
        surface_gradients: Some(normals),
        trace_ms,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;
    use ins_core::modules::sdf::SdfMlpConfig;
    use ins_scene::geometry::Vec3;

    /// The derivative of the surface point in a weight of the SDF equals finite differences of
    /// re-traced surfaces.
    #[test]
    fn surface_point_has_the_implicit_function_gradient() {
        let ad = Device::flex().autodiff();
        ad.seed(21);
        let mut mlp = SdfMlpConfig::new()
            .with_d_hidden(32)
            .with_depth(3)
            .with_skip_at(9)
            .with_d_features(4)
            .init(&ad);
        // Make the surface wobble so the derivative is not trivial.
        let w = mlp.layers[3].weight.val();
        let bump = Tensor::random(w.dims(), burn::tensor::Distribution::Normal(0.0, 0.02), &ad);
        mlp.layers[3].weight = Param::from_tensor((w + bump).detach());
        let net = SdfNet::Mlp(mlp);
        let mut rays = Rays::default();
        for (x, y) in [(0.05f32, 0.1f32), (-0.2, 0.15), (0.1, -0.25)] {
            rays.push(Vec3::new(x, y, 2.0), Vec3::NEG_Z, 0.5, 3.5);
        }
        let opts = TraceOptions {
            eps: 1e-7,
            max_steps: 200,
            ..Default::default()
        };
        let hits_for = |n: &SdfNet| -> Vec<f32> {
            let inner = n.valid();
            let t = sphere_trace(&rays, &opts, |p| sdf_at(&inner, p, &Device::flex()));
            assert!(t.hit.iter().all(|&h| h));
            (0..3)
                .flat_map(|i| rays.point(i, t.t[i]).to_array())
                .collect()
        };
        let x0 = hits_for(&net);
        let x0t = Tensor::<1>::from_floats(x0.as_slice(), &ad).reshape([3, 3]);
        let v = Tensor::<2>::from_floats([[0.0, 0.0, -1.0]; 3], &ad);
        // L = Σ z-coordinates of the surface points (they move along −z).
        let x = surface_point(&net, x0t, v);
        let grads = x.slice([0..3, 2..3]).sum().backward();
        let SdfNet::Mlp(m) = &net else { unreachable!() };
        let analytic = m.layers[3]
            .weight
            .val()
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let base = m.layers[3]
            .weight
            .val()
            .inner()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let dims = m.layers[3].weight.dims();
        let mut idx: Vec<usize> = (0..analytic.len()).collect();
        idx.sort_by(|&a, &b| analytic[b].abs().total_cmp(&analytic[a].abs()));
        for &i in idx.iter().take(3) {
            let eps = 1e-3f32;
            let z = |s: f32| {
                let mut vals = base.clone();
                vals[i] += s;
                let mut n2 = m.clone();
                n2.layers[3].weight = Param::from_tensor(
                    Tensor::<1>::from_floats(vals.as_slice(), &ad).reshape(dims),
                );
                let p = hits_for(&SdfNet::Mlp(n2));
                p[2] + p[5] + p[8]
            };
            let fd = (z(eps) - z(-eps)) / (2.0 * eps);
            assert!(
                (fd - analytic[i]).abs() < 5e-2 * analytic[i].abs().max(1e-2),
                "entry {i}: fd {fd} vs {}",
                analytic[i]
            );
        }
    }
}
