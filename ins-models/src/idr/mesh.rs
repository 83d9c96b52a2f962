//! A mesh of an IDR model's surface: the SDF sampled on a grid over the unit sphere's box
//! (exactly near the surface, interpolated from a coarse grid elsewhere), marching cubes of its
//! zero level set, and vertex colours from the rendering network under a style mix.

use anyhow::{Result, bail};
use burn::prelude::*;
use ins_core::mesh::{Grid, Mesh, marching_cubes};

use super::model::IdrModel;
use super::render::sdf_at;

/// Bytes one grid sample costs during extraction (value + bookkeeping).
const BYTES_PER_SAMPLE: u64 = 9;

/// Memory an extraction at `resolution³` needs, in bytes (samples, plus about a tenth for the
/// mesh itself).
pub fn memory_estimate(resolution: usize) -> u64 {
    let n = (resolution as u64).pow(3);
    n * BYTES_PER_SAMPLE + n / 10 * 8
}

/// Available memory from `/proc/meminfo` (Linux), if known.
fn available_memory() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with("MemAvailable:"))?;
    Some(line.split_whitespace().nth(1)?.parse::<u64>().ok()? * 1024)
}

/// Refuses resolutions whose grid would not fit in memory, with the estimate.
pub fn check_resolution(resolution: usize) -> Result<()> {
    if !(16..=4096).contains(&resolution) {
        bail!("--resolution {resolution}: choose between 16 and 4096");
    }
    let need = memory_estimate(resolution);
    let have = available_memory().unwrap_or(u64::MAX);
    if need > have / 2 {
        bail!(
            "--resolution {resolution} needs about {:.1} GB for its {}³ grid, but only {:.1} GB of memory is available; use a lower --resolution",
            need as f64 / 1e9,
            resolution,
            have as f64 / 1e9
        );
    }
    Ok(())
}

/// The SDF clipped to the unit sphere (`max(f, |x| − 1)`), so nothing outside the volume the
/// network was trained in becomes surface.
fn clipped(sdf: &mut dyn FnMut(&[f32]) -> Vec<f32>, points: &[f32]) -> Vec<f32> {
    let f = sdf(points);
    f.iter()
        .zip(points.chunks_exact(3))
        .map(|(&v, p)| v.max((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0))
        .collect()
}

/// Samples `sdf` on `res³` points of `[-1, 1]³` (x fastest): exactly in cells of a coarse
/// grid (every 4th sample) that come within 1.5 coarse cells of the surface, trilinearly
/// interpolated from the coarse grid everywhere else (where only the sign matters).
pub fn sample_narrow_band(res: usize, sdf: &mut dyn FnMut(&[f32]) -> Vec<f32>) -> Vec<f32> {
    let step = 4usize;
    let cres = (res - 1).div_ceil(step) + 1;
    let coord = |i: usize, r: usize| -1.0 + 2.0 * i as f32 / (r - 1) as f32;
    let fine_at = |i: usize| (i * step).min(res - 1);
    // Coarse values at fine positions i·step (clamped to the last sample).
    let mut pts = Vec::with_capacity(cres.pow(3) * 3);
    for k in 0..cres {
        for j in 0..cres {
            for i in 0..cres {
                pts.extend([
                    coord(fine_at(i), res),
                    coord(fine_at(j), res),
                    coord(fine_at(k), res),
                ]);
            }
        }
    }
    let coarse = clipped(sdf, &pts);
    let cidx = |i: usize, j: usize, k: usize| i + cres * (j + cres * k);
    let cell = 2.0 * step as f32 / (res - 1) as f32;
    let mut values = vec![0f32; res * res * res];
    let mut exact_points = Vec::new();
    let mut exact_index = Vec::new();
    for k in 0..res {
        let (ck, fk) = (
            (k / step).min(cres - 2),
            (k as f32 / step as f32 - ((k / step).min(cres - 2)) as f32).min(1.0),
        );
        for j in 0..res {
            let (cj, fj) = (
                (j / step).min(cres - 2),
                (j as f32 / step as f32 - ((j / step).min(cres - 2)) as f32).min(1.0),
            );
            for i in 0..res {
                let (ci, fi) = (
                    (i / step).min(cres - 2),
                    (i as f32 / step as f32 - ((i / step).min(cres - 2)) as f32).min(1.0),
                );
                let c = |a: usize, b: usize, d: usize| coarse[cidx(ci + a, cj + b, ck + d)];
                let corners = [
                    c(0, 0, 0),
                    c(1, 0, 0),
                    c(0, 1, 0),
                    c(1, 1, 0),
                    c(0, 0, 1),
                    c(1, 0, 1),
                    c(0, 1, 1),
                    c(1, 1, 1),
                ];
                let near = corners.iter().any(|v| v.abs() < 1.5 * cell) || {
                    let (lo, hi) = corners
                        .iter()
                        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
                    lo < 0.0 && hi > 0.0
                };
                let id = i + res * (j + res * k);
                if near {
                    exact_points.extend([coord(i, res), coord(j, res), coord(k, res)]);
                    exact_index.push(id);
                } else {
                    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
                    let x00 = lerp(corners[0], corners[1], fi);
                    let x10 = lerp(corners[2], corners[3], fi);
                    let x01 = lerp(corners[4], corners[5], fi);
                    let x11 = lerp(corners[6], corners[7], fi);
                    values[id] = lerp(lerp(x00, x10, fj), lerp(x01, x11, fj), fk);
                }
            }
        }
    }
    for (chunk_p, chunk_i) in exact_points
        .chunks(3 * 262_144)
        .zip(exact_index.chunks(262_144))
    {
        for (v, &id) in clipped(sdf, chunk_p).into_iter().zip(chunk_i) {
            values[id] = v;
        }
    }
    values
}

/// Extracts the surface of `model` at `resolution³` and colours its vertices with the
/// rendering network (view direction: against the normal) under `code` (`[1, n]`) if given.
pub fn extract_mesh(
    model: &IdrModel,
    resolution: usize,
    code: Option<Tensor<2>>,
    device: &Device,
) -> Result<(Mesh, Vec<[u8; 3]>)> {
    check_resolution(resolution)?;
    let sdf_net = model.sdf.clone();
    let mut sdf = |p: &[f32]| sdf_at(&sdf_net, p, device);
    let values = sample_narrow_band(resolution, &mut sdf);
    let mesh = marching_cubes(
        &Grid {
            res: [resolution; 3],
            min: [-1.0; 3],
            max: [1.0; 3],
            values: &values,
        },
        0.0,
    );
    let mut colors = Vec::with_capacity(mesh.vertices.len());
    for (vs, ns) in mesh.vertices.chunks(16384).zip(mesh.normals.chunks(16384)) {
        let m = vs.len();
        let x = Tensor::<1>::from_floats(vs.as_flattened(), device).reshape([m, 3]);
        let n_in = Tensor::<1>::from_floats(ns.as_flattened(), device).reshape([m, 3]);
        let (_, feat, g) = model.sdf.forward_with_gradient(x.clone());
        let rgb = model.shade(x, g, n_in.neg(), feat, code.clone());
        let v = rgb
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("reading vertex colours: {e:?}"))?;
        colors.extend(
            v.chunks_exact(3)
                .map(|c| std::array::from_fn(|k| (c[k].clamp(0.0, 1.0) * 255.0).round() as u8)),
        );
    }
    Ok((mesh, colors))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn narrow_band_sampling_gives_an_accurate_sphere() {
        let r = 0.6f32;
        let mut exact_calls = 0usize;
        let mut sdf = |p: &[f32]| {
            exact_calls += p.len() / 3;
            p.chunks_exact(3)
                .map(|q| (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() - r)
                .collect::<Vec<f32>>()
        };
        let res = 97;
        let values = sample_narrow_band(res, &mut sdf);
        let mesh = marching_cubes(
            &Grid {
                res: [res; 3],
                min: [-1.0; 3],
                max: [1.0; 3],
                values: &values,
            },
            0.0,
        );
        let area = 4.0 * std::f64::consts::PI * (r as f64).powi(2);
        let volume = 4.0 / 3.0 * std::f64::consts::PI * (r as f64).powi(3);
        assert!(
            (mesh.area() / area - 1.0).abs() < 0.02,
            "area {} vs {area}",
            mesh.area()
        );
        assert!(
            (mesh.volume() / volume - 1.0).abs() < 0.02,
            "volume {} vs {volume}",
            mesh.volume()
        );
        // Far fewer exact evaluations than samples.
        assert!(
            exact_calls < res * res * res / 3,
            "{exact_calls} exact evaluations"
        );
    }

    #[test]
    fn absurd_resolutions_are_refused_with_an_estimate() {
        let e = check_resolution(4000).unwrap_err().to_string();
        assert!(e.contains("GB") && e.contains("4000"), "{e}");
        assert!(check_resolution(8).is_err());
        assert!(check_resolution(64).is_ok());
    }
}
