//! Whole views rendered as a volume: a sparse probe of each ray finds those that stay clear of
//! the surface, and only the others get the full render of [`super::volume`]. Most of a view's
//! rays (the background, rays outside the unit sphere) are clear.

use burn::prelude::*;
use ins_scene::rays::Rays;

use super::model::IdrModel;
use super::volume::{
    VolumeSampling, behind, coarse_pass, host, ray_tensors, render_volume_with,
    unit_sphere_intervals,
};

/// How far (in units of the model's `1/s`) a ray must stay from the surface to be left clear
/// by [`render_volume_view`]: its opacity is then below `σ(−10)` ≈ 5e-5.
const CLEAR_MARGIN: f32 = 10.0;

/// The probe that finds the clear rays samples a ray this many times more sparsely than the
/// coarse pass.
const PROBE_DIVISOR: usize = 4;

/// A view's rays rendered as a volume (no gradient, samples at bin centres), as
/// [`render_volume`] but with the fine pass only where the coarse pass comes near the surface:
/// a ray whose coarse SDF stays above half the samples' spacing (the SDF is 1-Lipschitz, so
/// it cannot dip between them by more) plus `CLEAR_MARGIN / s` is clear to within 5e-5, and
/// most of a view's rays (the background, rays outside the unit sphere) are such. Colour
/// `[S·R, 3]` (style-major) and opacity `[R]` on the host.
pub fn render_volume_view(
    model: &IdrModel,
    rays: &Rays,
    codes: Option<Tensor<2>>,
    background: [f32; 3],
    opts: &VolumeSampling,
    device: &Device,
) -> (Vec<f32>, Vec<f32>) {
    let styles = codes.as_ref().map_or(1, |c| c.dims()[0]);
    let r = rays.len();
    let (near_v, far_v) = unit_sphere_intervals(rays);
    let mut rgb: Vec<f32> = if model.background.is_some() {
        let (origins, dirs) = ray_tensors(rays, device);
        let beyond = host(behind(
            model, rays, &origins, &dirs, &far_v, background, opts, None, device,
        ));
        beyond
            .iter()
            .copied()
            .cycle()
            .take(styles * r * 3)
            .collect()
    } else {
        background
            .iter()
            .copied()
            .cycle()
            .take(styles * r * 3)
            .collect()
    };
    let mut opacity = vec![0.0f32; r];
    let inside: Vec<usize> = (0..r).filter(|&i| far_v[i] > near_v[i]).collect();
    if inside.is_empty() {
        return (rgb, opacity);
    }
    let sub = |idx: &[usize]| Rays {
        origins: idx.iter().map(|&i| rays.origins[i]).collect(),
        directions: idx.iter().map(|&i| rays.directions[i]).collect(),
        near: idx.iter().map(|&i| near_v[i]).collect(),
        far: idx.iter().map(|&i| far_v[i]).collect(),
    };
    // The coarse pass over the rays inside the sphere; which of them come near the surface.
    let inner = sub(&inside);
    let near = Tensor::<1>::from_floats(inner.near.as_slice(), device);
    let far = Tensor::<1>::from_floats(inner.far.as_slice(), device);
    let (origins, dirs) = ray_tensors(&inner, device);
    let probe = VolumeSampling {
        coarse: (opts.coarse / PROBE_DIVISOR).max(2),
        ..*opts
    };
    let (_, f) = coarse_pass(model, &origins, &dirs, &near, &far, &probe, None);
    let c = probe.coarse;
    let f = host(f);
    let s = model
        .sharpness
        .as_ref()
        .map_or(opts.coarse_sharpness, |s| s.value())
        .max(1.0);
    let near_surface: Vec<usize> = (0..inside.len())
        .filter(|&j| {
            let spacing = (inner.far[j] - inner.near[j]) / c as f32;
            let least = f[j * c..(j + 1) * c]
                .iter()
                .copied()
                .fold(f32::INFINITY, f32::min);
            // NaN counts as near: such a ray gets the full render and shows it.
            least.partial_cmp(&(0.5 * spacing + CLEAR_MARGIN / s))
                != Some(std::cmp::Ordering::Greater)
        })
        .collect();
    if near_surface.is_empty() {
        return (rgb, opacity);
    }
    // The full render of those alone (their coarse pass again: a small share of the cost).
    let rays_near: Vec<usize> = near_surface.iter().map(|&j| inside[j]).collect();
    let out = render_volume_with(
        model,
        &sub(&rays_near),
        codes,
        background,
        opts,
        None,
        false,
        device,
    );
    let colour = host(out.rgb);
    let alpha = host(out.opacity);
    let m = rays_near.len();
    for (k, &i) in rays_near.iter().enumerate() {
        opacity[i] = alpha[k];
        for st in 0..styles {
            let (dst, src) = ((st * r + i) * 3, (st * m + k) * 3);
            rgb[dst..dst + 3].copy_from_slice(&colour[src..src + 3]);
        }
    }
    (rgb, opacity)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::idr::model::IdrArch;
    use crate::idr::volume::render_volume;
    use ins_scene::geometry::Vec3;

    /// A view rendered with the fine pass near the surface only equals the full render: the
    /// rays it leaves clear were clear, and it does leave some. With a background field, the
    /// rays it leaves clear show the field's colour as the full render does.
    #[test]
    fn a_view_rendered_near_the_surface_only_equals_the_full_render() {
        for background_field in [false, true] {
            let device = Device::flex();
            device.seed(5);
            let arch = IdrArch {
                background: background_field,
                ..IdrArch::small_volume()
            };
            // The fresh model's sphere of radius 0.5, at a trained model's sharpness (s ≈ 200;
            // at the starting 20 the margin is 0.5 and no ray inside the unit sphere is clear).
            let mut model = IdrModel::new(&arch, &device);
            model.sharpness = Some(ins_core::render::sdf_volume::Sharpness::new(0.53, &device));
            let mut rays = Rays::default();
            for i in 0..13 {
                for j in 0..13 {
                    let (x, y) = (-1.2 + 0.2 * i as f32, -1.2 + 0.2 * j as f32);
                    rays.push(Vec3::new(x, y, 2.0), Vec3::NEG_Z, 0.0, 4.0);
                }
            }
            let background = [0.2, 0.3, 0.4];
            let opts = VolumeSampling::default();
            let full = render_volume(&model, &rays, None, background, &opts, None, &device);
            let values = |t: Tensor<2>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
            let (full_rgb, full_opacity) = (
                values(full.rgb),
                values(full.opacity.reshape([rays.len(), 1])),
            );
            let (rgb, opacity) =
                render_volume_view(&model, &rays, None, background, &opts, &device);
            let worst = |a: &[f32], b: &[f32]| {
                a.iter()
                    .zip(b)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0f32, f32::max)
            };
            assert!(worst(&opacity, &full_opacity) < 1e-3);
            assert!(worst(&rgb, &full_rgb) < 1e-3, "field {background_field}");
            let hits = full_opacity.iter().filter(|&&o| o > 0.5).count();
            let left_clear = (0..rays.len())
                .filter(|&i| opacity[i] == 0.0 && full_opacity[i] > 0.0)
                .count();
            assert!(hits > 10, "{hits} rays meet the sphere");
            assert!(
                left_clear > 10,
                "{left_clear} rays inside the unit sphere were skipped"
            );
            // The field, not the fixed colour, shows where the ray is clear.
            let clear = (0..rays.len()).find(|&i| full_opacity[i] < 1e-3).unwrap();
            let shows_fixed = (0..3).all(|c| (rgb[clear * 3 + c] - background[c]).abs() < 1e-4);
            assert_eq!(shows_fixed, !background_field);
        }
    }
}
