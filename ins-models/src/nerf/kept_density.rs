//! Stylizing with the density kept (the default): the pretrained density is frozen, so every
//! sample's compositing weight along a ray is a constant of the step. The patch's samples are
//! weighed once without a graph, by the density network alone, and only those whose weight
//! reaches [`MIN_WEIGHT`] are shaded with a graph (SIM, AM, colour), each pixel being
//! `Σ wᵢ·cᵢ` over them plus the light that passes every sample times the background. A sample
//! left out would have moved its pixel by less than [`MIN_WEIGHT`] of its colour. On a room
//! capture's 64² patch the occupancy grid marches about 230 samples a ray, most in empty
//! space or behind the first surface, where shading them all cost 6.3 s a step on 2 cores.

use burn::prelude::*;
use ins_core::render::gather::select_parallel;
use ins_core::render::occupancy::OccupancyGrid;
use ins_core::shape_buckets::{pad_rows, padded_size};

use super::model::NerfModel;
use super::render::RenderRays;

/// Weight below which a sample is not shaded.
pub const MIN_WEIGHT: f32 = 1e-4;

/// A patch's samples weighed by the frozen density: the ones to shade and the light left.
pub struct Weighed {
    /// Field positions of the kept samples, `3` floats each.
    points: Vec<f32>,
    /// Their view directions, `3` floats each.
    dirs: Vec<f32>,
    /// Their compositing weights.
    weight: Vec<f32>,
    /// Kept samples of each ray, plus one past the end (`rays + 1` entries).
    offsets: Vec<usize>,
    /// Per ray, the light that passes all its samples (`1 − Σ wᵢ` over every sample).
    left: Vec<f32>,
    /// Samples marched in all.
    pub marched: usize,
}

impl Weighed {
    /// Kept samples.
    pub fn len(&self) -> usize {
        self.weight.len()
    }

    /// Whether no sample was kept.
    pub fn is_empty(&self) -> bool {
        self.weight.is_empty()
    }
}

/// Whether `model`'s density is its content module's alone (no stylizer, or the AM's density
/// blend λ at exactly 1): only then may the weights be taken from the density network.
pub fn density_is_the_content_modules(model: &NerfModel) -> bool {
    model.stylizer.as_ref().is_none_or(|st| {
        st.am
            .density
            .lambda
            .val()
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .is_ok_and(|v| v.iter().all(|&l| l == 1.0))
    })
}

/// Marches `rays` through `grid` (jittered by `seed`, at most `max_per_ray` samples each) and
/// weighs every sample by `model`'s density, without a graph.
pub fn weigh(
    model: &NerfModel,
    rays: &RenderRays,
    grid: &OccupancyGrid,
    max_per_ray: usize,
    seed: u64,
    device: &Device,
) -> Weighed {
    let r = rays.len();
    let m = grid.march(&rays.rays, max_per_ray, Some(seed));
    let mut x = Vec::with_capacity(m.len() * 3);
    for (&ray, &t) in m.ray.iter().zip(&m.t) {
        x.extend(
            grid.field_point(rays.rays.point(ray as usize, t))
                .to_array(),
        );
    }
    let field = model.field.valid();
    let inner = device.clone().inner();
    let mut sigma = Vec::with_capacity(m.len());
    for chunk in x.chunks(3 * 65536) {
        let n = chunk.len() / 3;
        let p = Tensor::<1>::from_floats(chunk, &inner).reshape([n, 3]);
        let d = field.density(p).into_data().convert::<f32>();
        sigma.extend(d.try_to_vec::<f32>().unwrap_or_else(|_| vec![0.0; n]));
    }
    let mut kept = Weighed {
        points: Vec::new(),
        dirs: Vec::new(),
        weight: Vec::new(),
        offsets: Vec::with_capacity(r + 1),
        left: Vec::with_capacity(r),
        marched: m.len(),
    };
    kept.offsets.push(0);
    for ray in 0..r {
        let (a, b) = (m.offsets[ray] as usize, m.offsets[ray + 1] as usize);
        // The compositing of `ins_core::render::volume::weights`, in f64 on the host.
        let mut optical_depth = 0f64;
        let mut total = 0f64;
        for k in a..b {
            let tau = f64::from(sigma[k]) * f64::from(m.delta[k]);
            let w = (-optical_depth).exp() * (1.0 - (-tau).exp());
            optical_depth += tau;
            total += w;
            if w >= f64::from(MIN_WEIGHT) {
                kept.points.extend_from_slice(&x[3 * k..3 * k + 3]);
                kept.dirs.extend(rays.view_dirs[ray].to_array());
                kept.weight.push(w as f32);
            }
        }
        kept.left.push((1.0 - total) as f32);
        kept.offsets.push(kept.weight.len());
    }
    kept
}

/// The patch's pixels under every style of `codes [S, n_styles]`, `[S·R, 3]` style-major:
/// the kept samples of `weighed` shaded by `model` on `device` (with a graph where `device`
/// has one), over `background`.
pub fn shade(
    model: &NerfModel,
    weighed: &Weighed,
    codes: Tensor<2>,
    background: [f32; 3],
    device: &Device,
) -> Tensor<2> {
    let r = weighed.left.len();
    let s = codes.dims()[0];
    let bg = Tensor::<1>::from_floats(background, device).reshape([1, 3]);
    let left = Tensor::<1>::from_floats(weighed.left.as_slice(), device).reshape([r, 1]);
    let behind = (left * bg).unsqueeze_dim::<3>(0).expand([s, r, 3]);
    if weighed.is_empty() {
        return behind.reshape([s * r, 3]);
    }
    // On GPUs the sample count and the widest ray are rounded up to a bucket, so the kernels
    // of one step serve the next (padding repeats the first sample, with no weight).
    let k = weighed.len();
    let n_eval = padded_size(k, device);
    let widest = (0..r)
        .map(|i| weighed.offsets[i + 1] - weighed.offsets[i])
        .max()
        .unwrap_or(0);
    let width = padded_size(widest.max(1), device);
    let (mut points, mut dirs, mut weight) = (
        weighed.points.clone(),
        weighed.dirs.clone(),
        weighed.weight.clone(),
    );
    pad_rows(&mut points, 3, n_eval);
    pad_rows(&mut dirs, 3, n_eval);
    weight.resize(n_eval, 0.0);
    let ev = model.evaluate(
        Tensor::<1>::from_floats(points.as_slice(), device).reshape([n_eval, 3]),
        model.field.color.encode_dirs(&dirs, device),
        Some(codes),
    );
    let w = Tensor::<1>::from_floats(weight.as_slice(), device).reshape([1, n_eval, 1]);
    let weighted = ev.rgb * w; // [S, n_eval, 3]
    // Each ray's kept samples in a padded [R, width] layout (`n_eval`: a zero row), summed.
    let mut index = vec![n_eval as i64; r * width];
    for ray in 0..r {
        for (j, sample) in (weighed.offsets[ray]..weighed.offsets[ray + 1]).enumerate() {
            index[ray * width + j] = sample as i64;
        }
    }
    let index = Tensor::<1, Int>::from_data(TensorData::new(index, [r * width]), device);
    let colour = select_parallel(
        Tensor::cat(vec![weighted, Tensor::zeros([s, 1, 3], device)], 1),
        1,
        index,
    )
    .reshape([s, r, width, 3])
    .sum_dim(2)
    .reshape([s, r, 3]);
    (colour + behind).reshape([s * r, 3])
}

#[cfg(test)]
mod tests {
    use burn::module::{Module, ModuleVisitor, Param};
    use burn::optim::GradientsParams;
    use ins_core::modules::field::{CimKind, Geometry};
    use ins_core::modules::style_position::StylePositionConfig;
    use ins_scene::geometry::Vec3;
    use ins_scene::rays::Rays;

    use super::*;
    use crate::nerf::model::NerfArch;
    use crate::nerf::render::{Sampling, render};

    /// `k × k` rays from a camera at (0.3, −0.2, 2.5) through a square of the plane z = 0.
    fn patch_rays(k: usize) -> RenderRays {
        let eye = Vec3::new(0.3, -0.2, 2.5);
        let mut rays = Rays::default();
        for j in 0..k {
            for i in 0..k {
                let target = Vec3::new(
                    -0.6 + 1.2 * i as f32 / (k - 1) as f32,
                    -0.6 + 1.2 * j as f32 / (k - 1) as f32,
                    0.0,
                );
                rays.origins.push(eye);
                rays.directions.push((target - eye).normalize());
                rays.near.push(0.5);
                rays.far.push(4.5);
            }
        }
        RenderRays {
            view_dirs: rays.directions.clone(),
            rays,
        }
    }

    /// Largest difference of every parameter's gradient between `a` and `b`, relative to the
    /// largest entry of `a`'s, over the parameters `a` reaches.
    struct Compare<'a> {
        a: &'a GradientsParams,
        b: &'a GradientsParams,
        worst: f32,
        compared: usize,
    }

    impl ModuleVisitor for Compare<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let Some(a) = self.a.get::<D>(param.id) else {
                return;
            };
            let b = self.b.get::<D>(param.id).expect("reached by both");
            let scale = a.clone().abs().max().into_scalar::<f32>().max(1e-12);
            let diff = (a - b).abs().max().into_scalar::<f32>();
            self.worst = self.worst.max(diff / scale);
            self.compared += 1;
        }
    }

    /// With the density frozen, shading the samples that weigh gives the full render's pixels
    /// and the stylizer's gradient, from a fraction of the samples.
    #[test]
    fn shading_the_samples_that_weigh_gives_the_full_renders_pixels_and_gradient() {
        let d = Device::flex().autodiff();
        d.seed(5);
        let arch = NerfArch {
            cim: CimKind::Grid,
            log2_table: 10,
            max_resolution: 32,
        };
        let position = StylePositionConfig::new()
            .with_grid_resolution(32)
            .with_grid_log2_table(10);
        let mut model = NerfModel::new(&arch, [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], &d)
            .with_stylizer(2, 16, &position, &d);
        // Dense content: rays turn opaque inside the box, as at a real surface.
        let Geometry::Grid(g) = &mut model.field.geometry else {
            unreachable!("a grid field")
        };
        let bias = g.out.bias.as_ref().expect("a bias").val();
        let mut bump = vec![0f32; bias.dims()[0]];
        bump[0] = 4.0;
        g.out.bias = Some(Param::from_tensor(
            (bias + Tensor::<1>::from_floats(bump.as_slice(), &d)).detach(),
        ));
        let grid = OccupancyGrid::new(16, Vec3::splat(-1.0), Vec3::splat(1.0), 0.03);
        let rays = patch_rays(8);
        let codes = Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0]], &d);
        let background = [0.2, 0.3, 0.4];
        let full = render(
            &model,
            &rays,
            Sampling::Occupancy {
                grid: &grid,
                max_per_ray: 256,
            },
            Some(codes.clone()),
            background,
            Some(11),
            &d,
        );
        let weighed = weigh(&model, &rays, &grid, 256, 11, &d);
        assert_eq!(weighed.marched, full.samples);
        assert!(
            weighed.len() * 2 < weighed.marched,
            "{} of {} samples kept",
            weighed.len(),
            weighed.marched
        );
        let fast = shade(&model, &weighed, codes, background, &d);
        let target = Tensor::<2>::random([2 * 64, 3], burn::tensor::Distribution::Default, &d);
        let loss = |p: Tensor<2>| (p - target.clone()).powi_scalar(2).sum();
        let host = |t: Tensor<2>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        let (a, b) = (host(full.fine.rgb.clone()), host(fast.clone()));
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(worst < 1e-3, "pixels differ by {worst}");
        let want = GradientsParams::from_grads(loss(full.fine.rgb).backward(), &model);
        let got = GradientsParams::from_grads(loss(fast).backward(), &model);
        let mut compare = Compare {
            a: &got,
            b: &want,
            worst: 0.0,
            compared: 0,
        };
        model.stylizer.visit(&mut compare);
        assert!(compare.compared >= 6, "{} parameters", compare.compared);
        assert!(
            compare.worst < 2e-3,
            "gradients differ by {}",
            compare.worst
        );
        eprintln!(
            "{} of {} samples shaded; pixels within {worst:e}, gradients within {:e}",
            weighed.len(),
            weighed.marched,
            compare.worst
        );
    }
}
