//! Whole-view renders through the occupancy grid that stop each ray once it is opaque (early
//! ray termination, as instant-ngp renders). Training needs every sample in one graph; a
//! render does not: samples are evaluated in rounds of growing length, composited on the host,
//! and a ray whose transmittance fell below [`MIN_TRANSMITTANCE`] takes no more samples. On
//! lego, most samples of a surface ray lie inside the object, behind its surface.

use anyhow::Result;
use burn::prelude::*;
use ins_core::render::occupancy::OccupancyGrid;

use super::model::NerfModel;
use super::render::RenderRays;

/// Transmittance below which a ray stops (what it could still add is below 1e-4).
pub const MIN_TRANSMITTANCE: f32 = 1e-4;
/// Samples per ray in the first round; each round doubles it.
const FIRST_ROUND: usize = 16;

/// Colour `[R·3]`, expected distance `[R]` (not divided by the opacity) and opacity `[R]` of
/// `rays` marched through `grid` (at most `max_per_ray` samples each, no jitter), under the
/// style code `code` (`[1, n_styles]`) or unstylized.
#[allow(clippy::too_many_arguments)]
pub fn render_early_stop(
    model: &NerfModel,
    rays: &RenderRays,
    grid: &OccupancyGrid,
    max_per_ray: usize,
    code: Option<Tensor<2>>,
    background: [f32; 3],
    device: &Device,
) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
    let r = rays.len();
    let m = grid.march(&rays.rays, max_per_ray, None);
    let mut transmittance = vec![1f32; r];
    let mut rgb = vec![0f32; 3 * r];
    let mut depth = vec![0f32; r];
    let mut cursor: Vec<usize> = m.offsets[..r].iter().map(|&o| o as usize).collect();
    let mut round = FIRST_ROUND;
    loop {
        // The next `round` samples of every ray still open.
        let mut owner = Vec::new();
        let mut index = Vec::new();
        for ray in 0..r {
            let end = m.offsets[ray + 1] as usize;
            if transmittance[ray] < MIN_TRANSMITTANCE || cursor[ray] >= end {
                continue;
            }
            let stop = (cursor[ray] + round).min(end);
            for k in cursor[ray]..stop {
                owner.push(ray);
                index.push(k);
            }
            cursor[ray] = stop;
        }
        if index.is_empty() {
            break;
        }
        let n = index.len();
        let mut x = Vec::with_capacity(3 * n);
        let mut dirs = Vec::with_capacity(3 * n);
        for (&ray, &k) in owner.iter().zip(&index) {
            x.extend(grid.field_point(rays.rays.point(ray, m.t[k])).to_array());
            dirs.extend(rays.view_dirs[ray].to_array());
        }
        let points = Tensor::<1>::from_floats(x.as_slice(), device).reshape([n, 3]);
        let ev = model.evaluate(
            points,
            model.field.color.encode_dirs(&dirs, device),
            code.clone(),
        );
        let sigma = host(ev.density)?;
        let colour = host(ev.rgb)?;
        // Samples of a ray are consecutive and in order along it.
        for (j, (&ray, &k)) in owner.iter().zip(&index).enumerate() {
            let t_before = transmittance[ray];
            if t_before < MIN_TRANSMITTANCE {
                continue;
            }
            let alpha = 1.0 - (-sigma[j] * m.delta[k]).exp();
            let w = t_before * alpha;
            for c in 0..3 {
                rgb[3 * ray + c] += w * colour[3 * j + c];
            }
            depth[ray] += w * m.t[k];
            transmittance[ray] = t_before * (1.0 - alpha);
        }
        round *= 2;
    }
    let mut opacity = Vec::with_capacity(r);
    for ray in 0..r {
        let t = transmittance[ray];
        for c in 0..3 {
            rgb[3 * ray + c] += t * background[c];
        }
        opacity.push(1.0 - t);
    }
    Ok((rgb, depth, opacity))
}

fn host<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("reading a render: {e:?}"))
}
