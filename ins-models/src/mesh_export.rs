//! A 3D run's surface written as a file: marching cubes through the run's [`SceneRender`],
//! vertex colours under a style mix, PLY or binary glTF, written atomically.

use std::path::Path;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::mesh::Mesh;
use ins_scene::geometry::{Similarity, Vec3};

use crate::run::any::load_scene_run;
use crate::run::scene_render::MeshOptions;

/// A mesh file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MeshFormat {
    /// Binary PLY (MeshLab, Blender, Open3D).
    Ply,
    /// Binary glTF 2.0 (Blender, three.js, web viewers, Windows' 3D Viewer).
    Glb,
}

impl MeshFormat {
    /// The format named by `path`'s extension.
    pub fn of(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "ply" => Some(Self::Ply),
            "glb" => Some(Self::Glb),
            _ => None,
        }
    }

    /// `format`, or the one `out`'s extension names; an error naming the file when neither says.
    pub fn choose(format: Option<Self>, out: &Path) -> Result<Self> {
        match (format, Self::of(out)) {
            (Some(f), _) | (None, Some(f)) => Ok(f),
            (None, None) => bail!(
                "{}: name the file .ply or .glb, or give --format ply|glb",
                out.display()
            ),
        }
    }
}

/// The coordinates a mesh is written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum MeshFrame {
    /// The run's own frame (DTU's unit sphere; a capture recentred and rescaled), where the
    /// viewer and the report look at it.
    #[default]
    Scene,
    /// The dataset's frame, its cameras' (DTU's millimetres, a COLMAP model's): to lay the mesh
    /// over the dataset's own points or ground truth.
    World,
}

/// `mesh` and its up direction moved from the scene frame back into the dataset's world frame
/// by the inverse of `to_scene`.
fn into_world(mesh: &mut Mesh, up: &mut Vec3, to_scene: &Similarity) {
    let back = to_scene.inverse();
    for v in &mut mesh.vertices {
        *v = back.apply_point(Vec3::from_array(*v)).to_array();
    }
    for n in &mut mesh.normals {
        *n = back.apply_direction(Vec3::from_array(*n)).to_array();
    }
    *up = back.apply_direction(*up);
}

/// Extracts the surface of the NeRF or IDR run in `run_dir` (colours under `mix`) and writes it
/// to `out` as `format` in `frame`; returns the summary `export mesh` prints: counts, area and
/// volume (in `frame`'s units), seconds, and for NeRF the density level and box.
pub fn export_mesh(
    run_dir: &Path,
    options: MeshOptions,
    mix: Option<&[f32]>,
    format: MeshFormat,
    frame: MeshFrame,
    out: &Path,
    device: &Device,
) -> Result<serde_json::Value> {
    crate::idr::mesh::check_resolution(options.resolution)?;
    let run = load_scene_run(run_dir, device, "a mesh")?;
    let code = run.code(mix, device)?;
    let mut m = run.mesh(options, code, device)?;
    if m.mesh.triangles.is_empty() {
        bail!(
            "{}: the surface is empty at this level (nothing to mesh)",
            run_dir.display()
        );
    }
    if frame == MeshFrame::World {
        into_world(&mut m.mesh, &mut m.up, &run.scene().to_scene);
    }
    write_mesh(&m.mesh, &m.colors, m.up.to_array(), format, out)?;
    let mut info = m.info;
    let summary = serde_json::json!({
        "mesh": out,
        "format": format!("{format:?}").to_lowercase(),
        "frame": format!("{frame:?}").to_lowercase(),
        "vertices": m.mesh.vertices.len(),
        "triangles": m.mesh.triangles.len(),
        "area": m.mesh.area(),
        "volume": m.mesh.volume(),
    });
    if let (Some(info), Some(s)) = (info.as_object_mut(), summary.as_object()) {
        info.extend(s.clone());
    }
    Ok(info)
}

/// Writes `mesh` atomically as `format`.
fn write_mesh(
    mesh: &Mesh,
    colors: &[[u8; 3]],
    up: [f32; 3],
    format: MeshFormat,
    out: &Path,
) -> Result<()> {
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    ins_io::write_atomic_with(out, |tmp| -> Result<()> {
        let mut f = std::io::BufWriter::new(
            std::fs::File::create(tmp).with_context(|| format!("writing {}", out.display()))?,
        );
        match format {
            MeshFormat::Ply => mesh.write_ply(&mut f, colors),
            MeshFormat::Glb => mesh.write_glb(&mut f, colors, up),
        }
        .with_context(|| format!("writing {}", out.display()))
    })
}
