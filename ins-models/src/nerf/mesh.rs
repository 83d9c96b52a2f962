//! A mesh of a NeRF run's density: marching cubes of the density at a level read off the run's
//! own renders, over the occupied part of the scene, with vertex colours from the (stylized)
//! radiance seen against the normal.
//!
//! The level: a radiance field has no zero set, and a fixed density threshold lands inside or
//! outside the surface depending on how sharp the run's density became. The surface the run
//! *renders* sits at its expected ray depth, so the level is the median density found at the
//! rendered surface points of a few training views: the iso-surface then passes where the
//! renders put the surface. A field that renders fog (its rays turn opaque only by adding up
//! many faint samples) would give a mesh of the fog; the level is then raised to the density
//! that makes one marching step half opaque.

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::mesh::{Grid, Mesh, marching_cubes};
use ins_scene::data::Split;
use ins_scene::geometry::Vec3;

use super::eval::render_camera;
use super::model::NerfModel;
use super::run::NerfRun;
use crate::run::scene::spread;

/// Points per batch when querying the field.
const BATCH: usize = 1 << 16;
/// Training views rendered to choose the level, and their longer side in pixels.
const LEVEL_VIEWS: usize = 8;
const LEVEL_SIZE: u32 = 96;

/// A NeRF mesh and how it was cut.
pub struct NerfMesh {
    /// The triangles (normals outward).
    pub mesh: Mesh,
    /// sRGB vertex colours.
    pub colors: Vec<[u8; 3]>,
    /// The density level of the surface.
    pub level: f32,
    /// The box meshed, `[min, max]` in the scene frame.
    pub bounds: (Vec3, Vec3),
    /// Samples along each axis.
    pub resolution: [usize; 3],
}

/// Density of `model` at the scene points `p` (flat xyz) under `code`, through the run's
/// contraction where it has one.
fn density_at(
    run: &NerfRun,
    model: &NerfModel,
    p: &[f32],
    code: Option<Tensor<2>>,
    device: &Device,
) -> Result<Vec<f32>> {
    let mut out = Vec::with_capacity(p.len() / 3);
    for chunk in p.chunks(3 * BATCH) {
        let n = chunk.len() / 3;
        let field: Vec<f32> = match run.grid() {
            Some(g) => chunk
                .chunks_exact(3)
                .flat_map(|q| g.field_point(Vec3::new(q[0], q[1], q[2])).to_array())
                .collect(),
            None => chunk.to_vec(),
        };
        let x = Tensor::<1>::from_floats(field.as_slice(), device).reshape([n, 3]);
        let dirs = model.field.color.encode_dirs(&vec![0.0; 3 * n], device);
        let ev = model.evaluate(x, dirs, code.clone());
        out.extend(
            ev.density
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("reading densities: {e:?}"))?,
        );
    }
    Ok(out)
}

/// The median density at the surface points of up to [`LEVEL_VIEWS`] training views rendered
/// at [`LEVEL_SIZE`] pixels or their own size if smaller (the level at which the mesh passes where renders put the surface).
pub fn surface_level(
    run: &NerfRun,
    model: &NerfModel,
    code: Option<Tensor<2>>,
    device: &Device,
) -> Result<f32> {
    let scene = run.scene();
    let views = spread(&scene.split(Split::Train), LEVEL_VIEWS);
    let mut points = Vec::new();
    for &v in &views {
        let cam = &scene.views[v].camera;
        // Never above the view's own size: a small capture's views say all they can at theirs.
        let s = (LEVEL_SIZE as f32 / cam.width.max(cam.height) as f32).min(1.0);
        let cam = cam.resized(
            ((cam.width as f32 * s).round() as u32).max(8),
            ((cam.height as f32 * s).round() as u32).max(8),
        );
        let r = render_camera(
            model,
            scene,
            &cam,
            run.sampling(),
            code.clone(),
            run.background(),
            device,
        )?;
        points.extend(
            r.surface_points(scene, &cam)
                .into_iter()
                .flatten()
                .flat_map(|p| p.to_array()),
        );
    }
    if points.is_empty() {
        bail!(
            "{}: no training view renders anything opaque: the run has no surface to mesh",
            run.dir.display()
        );
    }
    let mut d = density_at(run, model, &points, code, device)?;
    d.retain(|v| v.is_finite() && *v > 0.0);
    if d.is_empty() {
        bail!(
            "{}: zero density at every rendered surface point",
            run.dir.display()
        );
    }
    d.sort_by(f32::total_cmp);
    Ok(d[d.len() / 2])
}

/// The density that makes one marching step of the run's occupancy grid half opaque
/// (`ln 2 / step`); `None` without a grid. A well-trained field's surface level sits just above
/// it (lego: 62.5 against 59.1): its rays turn opaque within a step or two.
pub fn half_opaque_density(run: &NerfRun) -> Option<f32> {
    run.grid().map(|g| std::f32::consts::LN_2 / g.step)
}

/// The box worth meshing: the occupied cells of the run's occupancy grid (grid variant) within
/// the scene's bounds, or those bounds; for unbounded scenes, the uncontracted inner cube.
fn mesh_bounds(run: &NerfRun) -> Result<(Vec3, Vec3)> {
    let scene = run.scene();
    let (mut lo, mut hi) = match scene.contraction {
        Some(c) => (Vec3::splat(-c.radius), Vec3::splat(c.radius)),
        None => scene.bounds.aabb(),
    };
    if let Some(g) = run.grid() {
        let (glo, ghi) = g.occupied_bounds().with_context(|| {
            format!(
                "{}: the occupancy grid is empty (nothing to mesh)",
                run.dir.display()
            )
        })?;
        // One cell of margin so the surface closes inside the box.
        let cell = (Vec3::from(g.max) - Vec3::from(g.min)) / g.resolution as f32;
        lo = lo.max(glo - cell);
        hi = hi.min(ghi + cell);
    }
    if (hi - lo).min_element() <= 0.0 {
        bail!(
            "{}: the occupied region lies outside the scene's bounds",
            run.dir.display()
        );
    }
    Ok((lo, hi))
}

/// Extracts the surface of `model` (the run's model, or a stylized one under `code`) with
/// `resolution` samples along the longest side of the occupied box; `level` overrides the
/// density level chosen by [`surface_level`].
pub fn extract_mesh(
    run: &NerfRun,
    model: &NerfModel,
    resolution: usize,
    level: Option<f32>,
    code: Option<Tensor<2>>,
    device: &Device,
) -> Result<NerfMesh> {
    let scene = run.scene();
    if scene.forward_facing {
        bail!(
            "{}: a forward-facing scene's field lives in normalized device coordinates, where \
             surfaces stretch to infinity; meshes are exported from 360° scenes",
            run.dir.display()
        );
    }
    crate::idr::mesh::check_resolution(resolution)?;
    let level = match level {
        Some(l) if l.is_finite() && l > 0.0 => l,
        Some(l) => bail!("--level {l}: a density level is positive"),
        None => {
            let median = surface_level(run, model, code.clone(), device)?;
            match half_opaque_density(run) {
                Some(floor) if median < floor => {
                    eprintln!(
                        "the run renders its surfaces as fog (median density {median:.3} where \
                         its views turn opaque, below {floor:.3}, half opaque over one marching \
                         step): meshing at {floor:.3}; --level chooses another"
                    );
                    floor
                }
                _ => median,
            }
        }
    };
    let (lo, hi) = mesh_bounds(run)?;
    let ext = hi - lo;
    let res: [usize; 3] = std::array::from_fn(|k| {
        ((ext[k] / ext.max_element() * (resolution - 1) as f32).round() as usize + 1).max(2)
    });
    let at = |i: usize, k: usize| lo[k] + ext[k] * i as f32 / (res[k] - 1) as f32;
    // Query only points in occupied cells: the rest are below the grid's threshold, far below
    // any surface level.
    let total = res[0] * res[1] * res[2];
    let mut values = vec![0f32; total];
    let mut index = Vec::new();
    let mut points = Vec::new();
    for z in 0..res[2] {
        for y in 0..res[1] {
            for x in 0..res[0] {
                let p = Vec3::new(at(x, 0), at(y, 1), at(z, 2));
                if run.grid().is_none_or(|g| g.is_occupied(g.field_point(p))) {
                    index.push(x + res[0] * (y + res[1] * z));
                    points.extend(p.to_array());
                }
            }
        }
    }
    let density = density_at(run, model, &points, code.clone(), device)?;
    for (i, d) in index.into_iter().zip(density) {
        // Negated: marching cubes wants values rising outwards.
        values[i] = if d.is_finite() { -d } else { f32::MIN };
    }
    let mesh = marching_cubes(
        &Grid {
            res,
            min: lo.to_array(),
            max: hi.to_array(),
            values: &values,
        },
        -level,
    );
    let colors = vertex_colors(model, &mesh, run, code, device)?;
    Ok(NerfMesh {
        mesh,
        colors,
        level,
        bounds: (lo, hi),
        resolution: res,
    })
}

/// The radiance at each vertex seen from outside along its normal.
fn vertex_colors(
    model: &NerfModel,
    mesh: &Mesh,
    run: &NerfRun,
    code: Option<Tensor<2>>,
    device: &Device,
) -> Result<Vec<[u8; 3]>> {
    let mut colors = Vec::with_capacity(mesh.vertices.len());
    for (vs, ns) in mesh.vertices.chunks(BATCH).zip(mesh.normals.chunks(BATCH)) {
        let m = vs.len();
        let field: Vec<f32> = vs
            .iter()
            .flat_map(|v| {
                let p = Vec3::from(*v);
                run.grid().map_or(p, |g| g.field_point(p)).to_array()
            })
            .collect();
        let look: Vec<f32> = ns.iter().flat_map(|n| n.map(|c| -c)).collect();
        let x = Tensor::<1>::from_floats(field.as_slice(), device).reshape([m, 3]);
        let ev = model.evaluate(
            x,
            model.field.color.encode_dirs(&look, device),
            code.clone(),
        );
        let rgb = ev
            .rgb
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("reading vertex colours: {e:?}"))?;
        colors.extend(
            rgb.chunks_exact(3)
                .map(|c| std::array::from_fn(|k| (c[k].clamp(0.0, 1.0) * 255.0).round() as u8)),
        );
    }
    Ok(colors)
}
