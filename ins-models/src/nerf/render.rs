//! Rendering rays of a NeRF model: sample along the rays (occupancy-grid marching for the grid
//! variant, coarse-to-fine for the MLP), evaluate the field (under every style), composite.

use burn::prelude::*;
use ins_core::kernels::flex::is_flex;
use ins_core::render::gather::select_parallel;
use ins_core::render::marched_layout::DeviceSamples;
use ins_core::render::occupancy::OccupancyGrid;
use ins_core::render::samplers::{deltas, hierarchical, stratified};
use ins_core::render::volume::{Composite, composite, composite_ragged};
use ins_core::shape_buckets::padded_size;
use ins_scene::data::Scene;
use ins_scene::geometry::Vec3;
use ins_scene::rays::{RayBatch, Rays, flatten};

use super::early_stop::geometry_until_opaque;
use super::model::NerfModel;

/// Rays ready for rendering: the rays samples are placed along (NDC for forward-facing scenes)
/// and the unit world directions the colour head sees.
#[derive(Debug, Clone, Default)]
pub struct RenderRays {
    /// Sample positions are `origin + t · direction` of these, `t ∈ [near, far]`.
    pub rays: Rays,
    /// Unit viewing directions in the scene frame.
    pub view_dirs: Vec<Vec3>,
}

impl RenderRays {
    /// The rays of `rays` as scene `scene` renders them: forward-facing scenes in NDC (NeRF's
    /// forward-facing parametrisation, near plane 1), the others as they are.
    pub fn for_scene(scene: &Scene, rays: Rays) -> Self {
        let view_dirs = rays
            .directions
            .iter()
            .map(|d| d.normalize_or_zero())
            .collect();
        let rays = match scene.views.first() {
            Some(v) if scene.forward_facing => {
                rays.to_ndc(v.camera.width, v.camera.height, v.camera.fx, 1.0)
            }
            _ => rays,
        };
        Self { rays, view_dirs }
    }

    /// From a training batch.
    pub fn from_batch(scene: &Scene, batch: &RayBatch) -> Self {
        Self::for_scene(scene, batch.rays.clone())
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.rays.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.rays.is_empty()
    }

    /// Rays `start..end`.
    pub fn slice(&self, start: usize, end: usize) -> Self {
        Self {
            rays: Rays {
                origins: self.rays.origins[start..end].to_vec(),
                directions: self.rays.directions[start..end].to_vec(),
                near: self.rays.near[start..end].to_vec(),
                far: self.rays.far[start..end].to_vec(),
            },
            view_dirs: self.view_dirs[start..end].to_vec(),
        }
    }
}

/// The box a scene's field covers, `[min xyz, max xyz]`: the scene's bounding volume, the NDC
/// box for forward-facing scenes, or the contracted cube of unbounded ones.
pub fn scene_aabb(scene: &Scene) -> [f32; 6] {
    if scene.forward_facing {
        return [-1.5, -1.5, -1.0, 1.5, 1.5, 1.0];
    }
    if let Some(c) = scene.contraction {
        let e = c.extent();
        return [-e, -e, -e, e, e, e];
    }
    let (min, max) = scene.bounds.aabb();
    [min.x, min.y, min.z, max.x, max.y, max.z]
}

/// How samples are placed along rays.
#[derive(Debug, Clone, Copy)]
pub enum Sampling<'a> {
    /// March through occupied cells of a grid, at most `max_per_ray` samples per ray.
    Occupancy {
        /// The grid.
        grid: &'a OccupancyGrid,
        /// Cap per ray.
        max_per_ray: usize,
        /// `Some(t)`: each ray is shaded only up to where its transmittance falls below `t`
        /// (it turns opaque): the density is evaluated first, then the style and colour
        /// networks only at the samples in front. A pixel then differs by under `t` from the
        /// whole ray's, and its gradients by what the dropped samples carry; right only while
        /// the density does not train (stylization keeping it), where it spares the colour
        /// work of every sample behind a surface.
        until_opaque: Option<f32>,
    },
    /// NeRF: `coarse` stratified samples through the coarse field, then `fine` more from its
    /// weights, all through the fine field.
    CoarseFine {
        /// Stratified samples.
        coarse: usize,
        /// Importance samples.
        fine: usize,
    },
}

/// A render of `R` rays under `S` styles.
pub struct Rendered {
    /// Composited fine render over `S·R` rays (style-major).
    pub fine: Composite,
    /// The coarse render (MLP variant), `[R, 3]`.
    pub coarse_rgb: Option<Tensor<2>>,
    /// The fine sample points, `[N, 3]`.
    pub points: Tensor<2>,
    /// Raw density after the AM at those points, `[S, N]`.
    pub raw: Tensor<2>,
    /// Fine samples evaluated (per style).
    pub samples: usize,
}

fn tensor2(v: Vec<f32>, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    Tensor::<1>::from_floats(v.as_slice(), device).reshape([rows, cols])
}

fn repeat_rows(t: Tensor<2>, s: usize) -> Tensor<2> {
    if s == 1 {
        return t;
    }
    let [r, c] = t.dims();
    t.unsqueeze_dim::<3>(0)
        .expand([s, r, c])
        .reshape([s * r, c])
}

/// Renders `rays` with `model`, under the style codes `codes [S, n_styles]` if given. `seed`
/// jitters the samples (training); `None` places them deterministically (evaluation).
pub fn render(
    model: &NerfModel,
    rays: &RenderRays,
    sampling: Sampling,
    codes: Option<Tensor<2>>,
    background: [f32; 3],
    seed: Option<u64>,
    device: &Device,
) -> Rendered {
    match sampling {
        Sampling::Occupancy {
            grid,
            max_per_ray,
            until_opaque,
        } => render_marched(
            model,
            rays,
            grid,
            max_per_ray,
            until_opaque,
            codes,
            background,
            seed,
            device,
        ),
        Sampling::CoarseFine { coarse, fine } => {
            render_coarse_fine(model, rays, coarse, fine, codes, background, seed, device)
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn render_marched(
    model: &NerfModel,
    rays: &RenderRays,
    grid: &OccupancyGrid,
    max_per_ray: usize,
    until_opaque: Option<f32>,
    codes: Option<Tensor<2>>,
    background: [f32; 3],
    seed: Option<u64>,
    device: &Device,
) -> Rendered {
    let mut m = grid.march(&rays.rays, max_per_ray, seed);
    // With `until_opaque` on the CPU, the geometry of the samples evaluated and the kept ones'
    // rows. Off the CPU, choosing the samples would read the densities back in the middle of
    // the step (the GPU waiting for the host, issue 48): every sample is shaded there, and
    // those behind where their ray turns opaque are given no density, which composites the
    // same pixels.
    let on_cpu = is_flex(device);
    let mut geometry = None;
    if let Some(min_transmittance) = until_opaque.filter(|_| on_cpu && !m.is_empty()) {
        let (kept, raw, features, rows) =
            geometry_until_opaque(model, rays, grid, &m, min_transmittance, device);
        m = kept;
        geometry = Some((raw, features, rows));
    }
    if m.is_empty() {
        // Keep the graph connected when no ray meets an occupied cell: one inert sample.
        m.ray.push(0);
        m.t.push(rays.rays.near[0]);
        m.delta.push(0.0);
        m.offsets.iter_mut().skip(1).for_each(|o| *o = 1);
    }
    let n = m.len();
    // On GPUs the sample count is rounded up to a bucket, so the kernels of one step serve the
    // next; the extra samples repeat the first and no ray reads them.
    let n_eval = padded_size(n, device);
    let samples = DeviceSamples::upload(&m, n_eval, device);
    let (points, dirs) = sample_inputs(model, rays, grid, &samples, device);
    let ev = match geometry {
        Some((raw, features, mut index)) => {
            index.resize(n_eval, index[0]);
            let index: Vec<i64> = index.into_iter().map(i64::from).collect();
            let index = Tensor::<1, Int>::from_data(TensorData::new(index, [n_eval]), device);
            let raw = select_parallel(raw, 0, index.clone());
            let features = select_parallel(features, 0, index);
            model.shade(points.clone(), raw, features, dirs, codes)
        }
        None => model.evaluate(points.clone(), dirs, codes),
    };
    // Each ray's run of samples composited as it is: a padded `[R, width]` layout is as wide as
    // the ray with the most samples, ten times the samples on lego. Off the CPU, each ray stops
    // where it turns opaque (`until_opaque`, see above).
    let stop_below = until_opaque.filter(|_| !on_cpu).unwrap_or(0.0);
    Rendered {
        fine: composite_ragged(ev.density, ev.rgb, samples.spans(), background, stop_below),
        coarse_rgb: None,
        points,
        raw: ev.raw,
        samples: n,
    }
}

/// The field's inputs at the marched `samples`: the points `[rows, 3]` (in the grid's
/// coordinates) and the encoded view directions `[rows, d]`. Built on the device from the rays
/// and each sample's ray and distance: the host encodes one direction a ray, not one a sample
/// (issue 48: the host's work a step is a floor under the step on a GPU).
fn sample_inputs(
    model: &NerfModel,
    rays: &RenderRays,
    grid: &OccupancyGrid,
    samples: &DeviceSamples,
    device: &Device,
) -> (Tensor<2>, Tensor<2>) {
    let r = rays.len();
    let origins = tensor2(flatten(&rays.rays.origins), r, 3, device);
    let directions = tensor2(flatten(&rays.rays.directions), r, 3, device);
    let points = grid.field_points(samples.points(origins, directions));
    let dirs = samples.per_sample(
        model
            .field
            .color
            .encode_dirs(&flatten(&rays.view_dirs), device),
    );
    (points, dirs)
}

#[allow(clippy::too_many_arguments)]
fn render_coarse_fine(
    model: &NerfModel,
    rays: &RenderRays,
    n_coarse: usize,
    n_fine: usize,
    codes: Option<Tensor<2>>,
    background: [f32; 3],
    seed: Option<u64>,
    device: &Device,
) -> Rendered {
    let r = rays.len();
    let o = tensor2(flatten(&rays.rays.origins), r, 3, device);
    let d = tensor2(flatten(&rays.rays.directions), r, 3, device);
    let view_flat = flatten(&rays.view_dirs);
    let near = Tensor::<1>::from_floats(rays.rays.near.as_slice(), device);
    let far = Tensor::<1>::from_floats(rays.rays.far.as_slice(), device);
    let points = |t: &Tensor<2>| -> Tensor<2> {
        let s = t.dims()[1];
        (o.clone().unsqueeze_dim::<3>(1)
            + d.clone().unsqueeze_dim::<3>(1) * t.clone().unsqueeze_dim::<3>(2))
        .reshape([r * s, 3])
    };
    // Encoded directions, repeated for each of a ray's `s` samples.
    let view = |head: &ins_core::modules::color_head::ColorHead, s: usize| -> Tensor<2> {
        let enc = head.encode_dirs(&view_flat, device);
        let d = enc.dims()[1];
        enc.unsqueeze_dim::<3>(1)
            .expand([r, s, d])
            .reshape([r * s, d])
    };
    let t_c = stratified(near, far.clone(), n_coarse, seed);
    let coarse = model.coarse.as_ref().unwrap_or(&model.field);
    let (dens_c, rgb_c) = coarse.forward(points(&t_c), view(&coarse.color, n_coarse));
    let c = composite(
        dens_c.reshape([r, n_coarse]),
        rgb_c.reshape([r, n_coarse, 3]),
        t_c.clone(),
        deltas(t_c.clone(), far.clone()),
        background,
    );
    let t_f = hierarchical(t_c, c.weights(), n_fine, seed.map(|s| s ^ 0x5bd1_e995));
    let total = n_coarse + n_fine;
    let x = points(&t_f);
    let ev = model.evaluate(x.clone(), view(&model.field.color, total), codes);
    let s = ev.density.dims()[0];
    let delta = deltas(t_f.clone(), far);
    Rendered {
        fine: composite(
            ev.density.reshape([s * r, total]),
            ev.rgb.reshape([s * r, total, 3]),
            repeat_rows(t_f, s),
            repeat_rows(delta, s),
            background,
        ),
        coarse_rgb: Some(c.rgb),
        points: x,
        raw: ev.raw,
        samples: r * total,
    }
}
