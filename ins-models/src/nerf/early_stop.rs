//! Whole-view renders through the occupancy grid that stop each ray once it is opaque (early
//! ray termination, as instant-ngp renders). Training needs every sample in one graph; a
//! render does not: samples are evaluated in rounds of growing length, composited on the host,
//! and a ray whose transmittance fell below a threshold ([`INVISIBLE_TRANSMITTANCE`] for
//! pictures) takes no more samples. On lego, most samples of a surface ray lie inside the
//! object, behind its surface. A stylization step that keeps the density reads it in the same
//! rounds on the CPU ([`geometry_until_opaque`]).

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::render::marched_samples::MarchedSamples;
use ins_core::render::occupancy::OccupancyGrid;
use ins_core::shape_buckets::{pad_rows, padded_size};

use super::model::NerfModel;
use super::render::RenderRays;

/// Transmittance below which the rest of a ray is invisible: what it could still add to a
/// pixel is under half a level of an 8-bit image (1/510). Whole-view renders stop there (saved
/// pictures and frames are those of every sample to the rounding; PSNR moves in the fourth
/// decimal), and so does a stylization step's shading (its loss sees the pixels). Why not 1e-4,
/// instant-ngp's: a translucent field (a capture's fog) spends its last optical depths slowly,
/// and those from 6.2 (here) to 9.2 (1e-4) are samples nothing shows: 14 % of a 50-photo
/// capture's shaded samples and 17 % of its stylization step (docs/measurements.md).
pub const INVISIBLE_TRANSMITTANCE: f32 = 1.0 / 512.0;
/// Samples per ray in the first round; each round doubles it.
const FIRST_ROUND: usize = 16;

/// One way to colour a render's samples: `model`'s colour, under the style code `code`
/// (`[1, n_styles]`) or unstylized, over `background`.
#[derive(Clone)]
pub struct Look<'a> {
    /// The model whose colour (and stylizer) shades the samples.
    pub model: &'a NerfModel,
    /// Its style code, or `None` for its unstylized colour.
    pub code: Option<Tensor<2>>,
    /// What the light through a whole ray shows.
    pub background: [f32; 3],
}

/// Colour `[R·3]`, expected distance `[R]` (not divided by the opacity) and opacity `[R]` of
/// `rays` marched through `grid` (at most `max_per_ray` samples each, no jitter), under the
/// style code `code` (`[1, n_styles]`) or unstylized; a ray stops once its transmittance is
/// below `min_transmittance` ([`INVISIBLE_TRANSMITTANCE`] for pictures).
#[allow(clippy::too_many_arguments)]
pub fn render_early_stop(
    model: &NerfModel,
    rays: &RenderRays,
    grid: &OccupancyGrid,
    max_per_ray: usize,
    code: Option<Tensor<2>>,
    background: [f32; 3],
    min_transmittance: f32,
    device: &Device,
) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
    let look = Look {
        model,
        code,
        background,
    };
    let (mut rgb, depth, opacity) =
        render_looks(&[look], rays, grid, max_per_ray, min_transmittance, device)?;
    Ok((rgb.remove(0), depth, opacity))
}

/// Each look's colour `[R·3]`, then the shared distance `[R]` and opacity `[R]`.
pub type LooksRender = (Vec<Vec<f32>>, Vec<f32>, Vec<f32>);

/// [`render_early_stop`] of several looks at once, marched and composited with the density of
/// the first look's model: each look's colour `[R·3]`, the distance and the opacity. Where the
/// looks' models share their content module and keep its density (a stylized run and the
/// pretrained run it kept the density of), this is each look's own render for one pass of
/// the geometry: the pretrained frame beside each stylized one costs only its colour.
pub fn render_looks(
    looks: &[Look],
    rays: &RenderRays,
    grid: &OccupancyGrid,
    max_per_ray: usize,
    min_transmittance: f32,
    device: &Device,
) -> Result<LooksRender> {
    let model = looks.first().context("a render of no look")?.model;
    let r = rays.len();
    let density_first = looks.iter().all(|l| l.model.density_is_geometry());
    if looks.len() > 1 && !density_first {
        bail!("looks rendered together must keep their content module's density");
    }
    let m = grid.march(&rays.rays, max_per_ray, None);
    let mut transmittance = vec![1f32; r];
    let mut rgb = vec![vec![0f32; 3 * r]; looks.len()];
    let mut depth = vec![0f32; r];
    let mut cursor: Vec<usize> = m.offsets[..r].iter().map(|&o| o as usize).collect();
    let mut round = FIRST_ROUND;
    loop {
        // The next `round` samples of every ray still open.
        let index = m.next_round(&mut cursor, &transmittance, min_transmittance, round);
        if index.is_empty() {
            break;
        }
        let owner: Vec<usize> = index.iter().map(|&k| m.ray[k] as usize).collect();
        let n = index.len();
        let mut x = Vec::with_capacity(3 * n);
        let mut dirs = Vec::with_capacity(3 * n);
        for (&ray, &k) in owner.iter().zip(&index) {
            x.extend(grid.field_point(rays.rays.point(ray, m.t[k])).to_array());
            dirs.extend(rays.view_dirs[ray].to_array());
        }
        let points = Tensor::<1>::from_floats(x.as_slice(), device).reshape([n, 3]);
        // `shaded[f]` is the sample whose colour is row `f` of each look's `colours`.
        let (sigma, colours, shaded) = if density_first {
            // The density first; the stylizer and the colour only in front of where each
            // ray turns opaque (a stylized field's colour is most of a sample's cost).
            let (raw, features) = model.geometry(points.clone());
            let sigma = host(model.field.geometry.activate(raw.clone()))?;
            let mut open = transmittance.clone();
            let mut shaded = Vec::with_capacity(n);
            for (j, (&ray, &k)) in owner.iter().zip(&index).enumerate() {
                // As the compositing below steps it, so both keep the same samples.
                if open[ray] >= min_transmittance {
                    shaded.push(j);
                    open[ray] *= 1.0 - (1.0 - (-sigma[j] * m.delta[k]).exp());
                }
            }
            let rows: Vec<i64> = shaded.iter().map(|&j| j as i64).collect();
            let rows = Tensor::<1, Int>::from_data(TensorData::new(rows, [shaded.len()]), device);
            let shaded_dirs: Vec<f32> = shaded
                .iter()
                .flat_map(|&j| dirs[3 * j..3 * j + 3].iter().copied())
                .collect();
            let (x, raw, features) = (
                points.select(0, rows.clone()),
                raw.select(0, rows.clone()),
                features.select(0, rows),
            );
            let colours = looks
                .iter()
                .map(|l| {
                    let dirs = l.model.field.color.encode_dirs(&shaded_dirs, device);
                    let ev = l.model.shade(
                        x.clone(),
                        raw.clone(),
                        features.clone(),
                        dirs,
                        l.code.clone(),
                    );
                    host(ev.rgb)
                })
                .collect::<Result<Vec<_>>>()?;
            (sigma, colours, shaded)
        } else {
            let ev = model.evaluate(
                points,
                model.field.color.encode_dirs(&dirs, device),
                looks[0].code.clone(),
            );
            (host(ev.density)?, vec![host(ev.rgb)?], (0..n).collect())
        };
        // Samples of a ray are consecutive and in order along it.
        for (f, &j) in shaded.iter().enumerate() {
            let (ray, k) = (owner[j], index[j]);
            let t_before = transmittance[ray];
            if t_before < min_transmittance {
                continue;
            }
            let alpha = 1.0 - (-sigma[j] * m.delta[k]).exp();
            let w = t_before * alpha;
            for (rgb, colour) in rgb.iter_mut().zip(&colours) {
                for c in 0..3 {
                    rgb[3 * ray + c] += w * colour[3 * f + c];
                }
            }
            depth[ray] += w * m.t[k];
            transmittance[ray] = t_before * (1.0 - alpha);
        }
        round *= 2;
    }
    let mut opacity = Vec::with_capacity(r);
    for ray in 0..r {
        let t = transmittance[ray];
        for (rgb, look) in rgb.iter_mut().zip(looks) {
            for c in 0..3 {
                rgb[3 * ray + c] += t * look.background[c];
            }
        }
        opacity.push(1.0 - t);
    }
    Ok((rgb, depth, opacity))
}

/// The geometry of `m`'s samples along `rays` up to where each ray turns opaque: the samples
/// [`MarchedSamples::until_opaque`] keeps, the raw density `[E]` and features `[E, F]` of
/// every sample evaluated, and the kept samples' rows in them. What a stylization step that
/// keeps the density shades on the CPU. The samples are evaluated in rounds of growing
/// length, so that most of those behind a surface are not (half of a capture's marched
/// samples). Each round reads the densities back: off the CPU each ray's composite stops on
/// the device instead (`render.rs`, [`composite_ragged`](ins_core::render::volume::composite_ragged)'s
/// `stop_below`).
pub(crate) fn geometry_until_opaque(
    model: &NerfModel,
    rays: &RenderRays,
    grid: &OccupancyGrid,
    m: &MarchedSamples,
    min_transmittance: f32,
    device: &Device,
) -> (MarchedSamples, Tensor<1>, Tensor<2>, Vec<u32>) {
    let r = m.offsets.len() - 1;
    let mut cursor: Vec<usize> = m.offsets[..r].iter().map(|&o| o as usize).collect();
    let mut transmittance = vec![1f32; r];
    // Samples never evaluated lie behind a point where their ray was already opaque.
    let mut density = vec![0f32; m.len()];
    let mut row_of = vec![0u32; m.len()];
    let (mut raws, mut features) = (Vec::new(), Vec::new());
    let mut rows = 0;
    let mut round = FIRST_ROUND;
    loop {
        let index = m.next_round(&mut cursor, &transmittance, min_transmittance, round);
        if index.is_empty() {
            break;
        }
        let n_eval = padded_size(index.len(), device);
        let mut x = Vec::with_capacity(3 * n_eval);
        for &k in &index {
            let point = rays.rays.point(m.ray[k] as usize, m.t[k]);
            x.extend(grid.field_point(point).to_array());
        }
        pad_rows(&mut x, 3, n_eval);
        let points = Tensor::<1>::from_floats(x.as_slice(), device).reshape([n_eval, 3]);
        let (raw, feature) = model.geometry(points);
        // Unreadable densities keep every sample: slower, never wrong.
        let sigma =
            host(model.field.geometry.activate(raw.clone())).unwrap_or_else(|_| vec![0.0; n_eval]);
        for (j, &k) in index.iter().enumerate() {
            density[k] = sigma[j];
            row_of[k] = (rows + j) as u32;
            transmittance[m.ray[k] as usize] *= (-sigma[j].max(0.0) * m.delta[k]).exp();
        }
        rows += n_eval;
        raws.push(raw);
        features.push(feature);
        round = round.saturating_mul(2);
    }
    let (kept, index) = m.until_opaque(&density, min_transmittance);
    let kept_rows = index.iter().map(|&k| row_of[k as usize]).collect();
    let (raw, features) = if raws.len() == 1 {
        (raws.remove(0), features.remove(0))
    } else {
        (Tensor::cat(raws, 0), Tensor::cat(features, 0))
    };
    (kept, raw, features, kept_rows)
}

fn host<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("reading a render: {e:?}"))
}

#[cfg(test)]
mod tests {
    use burn::module::Param;
    use ins_core::render::occupancy::OccupancyGrid;
    use ins_scene::geometry::Vec3;

    use super::*;
    use crate::nerf::render::{Sampling, render};
    use crate::nerf::test_models::{dense_kept_density, patch_rays, stylized_model};

    /// The largest difference between an early-stopped render of `model` (rays stopped below
    /// `min_transmittance`) and a render of every sample (colour, opacity), under the first
    /// style.
    fn against_full_render(model: &NerfModel, min_transmittance: f32, d: &Device) -> (f32, f32) {
        let grid = OccupancyGrid::new(16, Vec3::splat(-1.0), Vec3::splat(1.0), 0.03);
        let rays = patch_rays(8);
        let code = Tensor::<2>::from_floats([[1.0, 0.0]], d);
        let (rgb, _, opacity) = render_early_stop(
            model,
            &rays,
            &grid,
            256,
            Some(code.clone()),
            [0.2; 3],
            min_transmittance,
            d,
        )
        .unwrap();
        let sampling = Sampling::Occupancy {
            grid: &grid,
            max_per_ray: 256,
            until_opaque: None,
        };
        let full = render(model, &rays, sampling, Some(code), [0.2; 3], None, d);
        let worst = |a: &[f32], b: Vec<f32>| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0f32, f32::max)
        };
        (
            worst(&rgb, host(full.fine.rgb).unwrap()),
            worst(&opacity, host(full.fine.opacity).unwrap()),
        )
    }

    /// A pretrained field and its stylization that kept its density, rendered together: each
    /// look is its own render (the geometry read once).
    #[test]
    fn looks_rendered_together_are_their_own_renders() {
        let d = Device::flex();
        let mut stylized = dense_kept_density(stylized_model(3, &d));
        let pretrained = NerfModel {
            stylizer: None,
            ..stylized.clone()
        };
        // A stylizer that changes the colour (a fresh one is the identity).
        let st = stylized.stylizer.as_mut().unwrap();
        st.am.feature.gamma = Param::from_tensor(Tensor::from_floats([0.3], &d));
        let grid = OccupancyGrid::new(16, Vec3::splat(-1.0), Vec3::splat(1.0), 0.03);
        let rays = patch_rays(8);
        let code = Tensor::<2>::from_floats([[0.0, 1.0]], &d);
        let looks = [
            Look {
                model: &pretrained,
                code: None,
                background: [0.2; 3],
            },
            Look {
                model: &stylized,
                code: Some(code.clone()),
                background: [0.7, 0.1, 0.3],
            },
        ];
        let (rgb, depth, opacity) =
            render_looks(&looks, &rays, &grid, 256, INVISIBLE_TRANSMITTANCE, &d).unwrap();
        let worst = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0f32, f32::max)
        };
        for (look, rgb) in looks.iter().zip(&rgb) {
            let (want, want_depth, want_opacity) = render_early_stop(
                look.model,
                &rays,
                &grid,
                256,
                look.code.clone(),
                look.background,
                INVISIBLE_TRANSMITTANCE,
                &d,
            )
            .unwrap();
            assert!(worst(rgb, &want) < 1e-6, "colour {}", worst(rgb, &want));
            assert!(worst(&depth, &want_depth) < 1e-6 && worst(&opacity, &want_opacity) < 1e-6);
        }
        // The two looks differ: the stylizer ran for the second only.
        assert!(worst(&rgb[0], &rgb[1]) > 1e-3);
    }

    /// The rounds keep exactly the samples (and their geometry) that every sample's density
    /// read at once keeps, while evaluating fewer.
    #[test]
    fn geometry_read_in_rounds_keeps_what_every_sample_keeps() {
        let d = Device::flex();
        let model = dense_kept_density(stylized_model(3, &d));
        let grid = OccupancyGrid::new(16, Vec3::splat(-1.0), Vec3::splat(1.0), 0.03);
        let rays = patch_rays(8);
        let m = grid.march(&rays.rays, 256, Some(5));
        let (kept, raw, features, rows) =
            geometry_until_opaque(&model, &rays, &grid, &m, INVISIBLE_TRANSMITTANCE, &d);
        assert!(
            raw.dims()[0] < m.len(),
            "{} of {} evaluated",
            raw.dims()[0],
            m.len()
        );
        let x: Vec<f32> = (0..m.len())
            .flat_map(|k| {
                let p = rays.rays.point(m.ray[k] as usize, m.t[k]);
                grid.field_point(p).to_array()
            })
            .collect();
        let x = Tensor::<1>::from_floats(x.as_slice(), &d).reshape([m.len(), 3]);
        let (all_raw, all_features) = model.field.geometry.forward(x);
        let density = host(model.field.geometry.activate(all_raw.clone())).unwrap();
        let (want, index) = m.until_opaque(&density, INVISIBLE_TRANSMITTANCE);
        assert!(want.len() * 2 < m.len(), "the rays did not turn opaque");
        assert_eq!((&kept.offsets, &kept.t), (&want.offsets, &want.t));
        let pick = |v: &[u32]| {
            let v: Vec<i64> = v.iter().map(|&i| i as i64).collect();
            Tensor::<1, Int>::from_data(TensorData::new(v.clone(), [v.len()]), &d)
        };
        let worst = |a: Tensor<2>, b: Tensor<2>| (a - b).abs().max().into_scalar::<f32>();
        let raw_diff = worst(
            raw.select(0, pick(&rows)).reshape([-1, 1]),
            all_raw.select(0, pick(&index)).reshape([-1, 1]),
        );
        let feature_diff = worst(
            features.select(0, pick(&rows)),
            all_features.select(0, pick(&index)),
        );
        assert!(
            raw_diff < 1e-5 && feature_diff < 1e-5,
            "{raw_diff} {feature_diff}"
        );
    }

    #[test]
    fn early_stopped_renders_match_every_sample_rendered() {
        let d = Device::flex();
        let mut model = dense_kept_density(stylized_model(3, &d));
        // The density kept: it is read first, the stylizer runs only in front.
        assert!(model.density_is_geometry());
        let (rgb, opacity) = against_full_render(&model, 1e-4, &d);
        assert!(
            rgb < 2e-4 && opacity < 2e-4,
            "colour {rgb}, opacity {opacity}"
        );
        // Pictures' threshold: within half an 8-bit level.
        let (rgb, opacity) = against_full_render(&model, INVISIBLE_TRANSMITTANCE, &d);
        assert!(
            rgb < 1.0 / 510.0 && opacity < 1.0 / 510.0,
            "colour {rgb}, opacity {opacity}"
        );
        // A stylized density (λ ≠ 1): every sample of a round is evaluated with the stylizer.
        let st = model.stylizer.as_mut().unwrap();
        st.am.density.lambda = Param::from_tensor(Tensor::from_floats([0.9], &d));
        assert!(!model.density_is_geometry());
        let (rgb, opacity) = against_full_render(&model, 1e-4, &d);
        assert!(
            rgb < 2e-4 && opacity < 2e-4,
            "colour {rgb}, opacity {opacity}"
        );
    }
}
