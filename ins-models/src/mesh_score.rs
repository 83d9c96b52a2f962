//! A 3D run's surface scored against a reference surface (DTU's ground-truth points, or the
//! true surface `data synth --format dtu` writes): the run's mesh (the one `export mesh`
//! writes), points drawn evenly over it, those the capture's cameras see (the mesh hiding
//! itself; the underside on the table is no error), and their distances to the reference both
//! ways ([`ins_core::mesh::surface_distance`]), in the reference's own units.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::mesh::visibility::seen_by;
use ins_core::mesh::{SurfaceDistance, sample_surface, surface_distance};
use ins_scene::geometry::Vec3;
use serde::Serialize;

use crate::run::any::load_scene_run;
use crate::run::scene_render::MeshOptions;

/// How far (scene units, the unit sphere's radius 1) a point on the mesh may lie behind the
/// mesh's depth at its pixel and still count as seen: a few pixels' depth on a surface seen
/// at a grazing angle (a 400-pixel DTU view spends about 0.004 a pixel).
const SEEN_TOLERANCE: f32 = 0.02;

/// How a mesh is scored.
#[derive(Debug, Clone, Copy)]
pub struct MeshScoreOptions {
    /// The mesh: marching cubes' resolution (and NeRF's density level).
    pub mesh: MeshOptions,
    /// Points drawn over the mesh.
    pub samples: usize,
    /// Beyond this distance (the reference's units) a point is an outlier; default a tenth of
    /// the unit sphere's radius (DTU's 20 mm cap on scan37 is 0.08 of it).
    pub max_distance: Option<f64>,
    /// Precision and recall count within this distance (the reference's units); default a
    /// hundredth of the unit sphere's radius.
    pub threshold: Option<f64>,
}

impl Default for MeshScoreOptions {
    fn default() -> Self {
        Self {
            mesh: MeshOptions {
                resolution: 256,
                level: None,
            },
            samples: 200_000,
            max_distance: None,
            threshold: None,
        }
    }
}

/// A run's surface against a reference.
#[derive(Debug, Clone, Serialize)]
pub struct MeshScore {
    /// The distances, in the reference's units.
    #[serde(flatten)]
    pub distance: SurfaceDistance,
    /// The reference's units per unit of the scene's frame (its unit sphere's radius, for DTU).
    pub units_per_scene_unit: f64,
    /// Points read from the reference.
    pub reference_points: usize,
    /// Share of the points drawn over the mesh that no camera of the capture sees (left out).
    pub unseen: f64,
    /// The mesh's vertices and triangles.
    pub vertices: usize,
    pub triangles: usize,
    /// Seconds taken, the mesh included.
    pub seconds: f64,
}

/// Scores the surface of the NeRF or IDR run in `run_dir` against the points of the PLY
/// `reference` (vertices of a point cloud or a mesh), given in the frame of the run's
/// dataset (its cameras' world frame).
pub fn score_mesh(
    run_dir: &Path,
    reference: &Path,
    options: &MeshScoreOptions,
    device: &Device,
) -> Result<MeshScore> {
    let start = Instant::now();
    crate::idr::mesh::check_resolution(options.mesh.resolution)?;
    if options.samples == 0 {
        bail!("--samples 0: draw at least one point over the mesh");
    }
    let world = ins_scene::data::ply_points::read_ply_points(reference)
        .with_context(|| format!("reading the reference surface {}", reference.display()))?;
    if world.is_empty() {
        bail!("{}: the reference holds no points", reference.display());
    }
    let run = load_scene_run(run_dir, device, "a mesh")?;
    let to_scene = run.scene().to_scene;
    let scene_per_unit = to_scene.scale as f64;
    let reference_scene: Vec<Vec3> = world
        .iter()
        .map(|p| to_scene.apply_point(p.as_vec3()))
        .collect();
    let m = run.mesh(options.mesh, None, device)?;
    if m.mesh.triangles.is_empty() {
        bail!(
            "{}: the surface is empty (nothing to score)",
            run_dir.display()
        );
    }
    let drawn = sample_surface(&m.mesh, options.samples, 0);
    let cameras: Vec<_> = run.scene().views.iter().map(|v| v.camera.clone()).collect();
    let seen = seen_by(&m.mesh, &drawn, &cameras, SEEN_TOLERANCE);
    let surface: Vec<Vec3> = drawn
        .iter()
        .zip(&seen)
        .filter(|&(_, &s)| s)
        .map(|(&p, _)| p)
        .collect();
    let unseen = 1.0 - surface.len() as f64 / drawn.len().max(1) as f64;
    let scene_distance = |d: Option<f64>, default: f64| -> Result<f32> {
        match d {
            Some(d) if !(d > 0.0 && d.is_finite()) => {
                bail!("a distance of {d}: give a positive one")
            }
            Some(d) => Ok((d * scene_per_unit) as f32),
            None => Ok(default as f32),
        }
    };
    let max_distance = scene_distance(options.max_distance, 0.1)?;
    let threshold = scene_distance(options.threshold, 0.01)?;
    // The grids' cell: about the reference's spacing, if it covers what the mesh covers.
    let spacing = (m.mesh.area() / reference_scene.len() as f64).sqrt() as f32;
    let d = surface_distance(&surface, &reference_scene, max_distance, threshold, spacing);
    let to_units = |x: f64| x / scene_per_unit;
    let distance = SurfaceDistance {
        accuracy: to_units(d.accuracy),
        completeness: to_units(d.completeness),
        chamfer: to_units(d.chamfer),
        max_distance: to_units(d.max_distance),
        threshold: to_units(d.threshold),
        ..d
    };
    Ok(MeshScore {
        distance,
        units_per_scene_unit: 1.0 / scene_per_unit,
        reference_points: world.len(),
        unseen,
        vertices: m.mesh.vertices.len(),
        triangles: m.mesh.triangles.len(),
        seconds: start.elapsed().as_secs_f64(),
    })
}
