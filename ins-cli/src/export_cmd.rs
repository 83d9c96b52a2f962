//! `ins-cli export mesh`: a NeRF or IDR run's surface as PLY or binary glTF.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use clap::{Args, ValueEnum};
use ins_core::mesh::Mesh;
use ins_core::train::RunFolder;
use ins_models::idr::{IdrRun, IdrRunConfig};
use ins_models::nerf::{NerfRun, NerfRunConfig};
use ins_scene::paths::scene_up;

use crate::common::DeviceArgs;

/// A mesh file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MeshFormat {
    /// Binary PLY (MeshLab, Blender, Open3D).
    Ply,
    /// Binary glTF 2.0 (Blender, three.js, web viewers, Windows' 3D Viewer).
    Glb,
}

impl MeshFormat {
    /// The format named by `path`'s extension.
    fn of(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "ply" => Some(Self::Ply),
            "glb" => Some(Self::Glb),
            _ => None,
        }
    }
}

#[derive(Args, Debug)]
pub struct ExportMesh {
    /// Run folder written by `train nerf` or `train idr` (pretrained or stylized).
    #[arg(long)]
    run: PathBuf,
    /// Samples along the longest side of the grid marching cubes runs on.
    #[arg(long, default_value_t = 256)]
    resolution: usize,
    /// Style weights for the vertex colours (stylized runs; default: the first style).
    #[arg(long, value_delimiter = ',')]
    mix: Option<Vec<f32>>,
    /// NeRF: the density of the surface (default: the median density at the surface the run
    /// renders in its training views).
    #[arg(long)]
    level: Option<f32>,
    /// File format (default: from --out's extension).
    #[arg(long, value_enum)]
    format: Option<MeshFormat>,
    /// Output .ply or .glb.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn export_mesh(a: ExportMesh) -> Result<()> {
    let format = match (a.format, MeshFormat::of(&a.out)) {
        (Some(f), _) | (None, Some(f)) => f,
        (None, None) => bail!(
            "{}: name the file .ply or .glb, or give --format ply|glb",
            a.out.display()
        ),
    };
    let device = a.device.device()?;
    let summary = export(
        &a.run,
        a.resolution,
        a.mix.as_deref(),
        a.level,
        format,
        &a.out,
        &device,
    )?;
    println!("{summary}");
    Ok(())
}

/// Extracts the surface of the NeRF or IDR run `run` at `resolution` (colours under `mix`,
/// NeRF density `level` or the run's own) and writes it to `out` as `format`; returns what the
/// command prints (counts, area, volume, the level and box for NeRF, seconds).
pub fn export(
    run_dir: &Path,
    resolution: usize,
    mix: Option<&[f32]>,
    level: Option<f32>,
    format: MeshFormat,
    out: &Path,
    device: &Device,
) -> Result<serde_json::Value> {
    let config = RunFolder::new(run_dir).config();
    let (mesh, colors, up, mut info) = if NerfRunConfig::from_file(&config).is_ok() {
        let run = NerfRun::load(run_dir, device)?;
        let code = run.code(mix, device)?;
        let started = std::time::Instant::now();
        let m = ins_models::nerf::mesh::extract_mesh(
            &run,
            &run.model.valid(),
            resolution,
            level,
            code,
            device,
        )?;
        let info = serde_json::json!({
            "level": m.level,
            "level_floor": ins_models::nerf::mesh::half_opaque_density(&run),
            "grid": m.resolution,
            "box": [m.bounds.0.to_array(), m.bounds.1.to_array()],
            "seconds": started.elapsed().as_secs_f64(),
        });
        (m.mesh, m.colors, scene_up(run.scene()), info)
    } else if IdrRunConfig::from_file(&config).is_ok() {
        if level.is_some() {
            bail!("--level is a NeRF density; an IDR run is meshed at its SDF's zero set");
        }
        ins_models::idr::mesh::check_resolution(resolution)?;
        let run = IdrRun::load(run_dir, device)?;
        let code = run.code(mix, device)?;
        let started = std::time::Instant::now();
        let (mesh, colors) =
            ins_models::idr::mesh::extract_mesh(&run.model.valid(), resolution, code, device)?;
        let info = serde_json::json!({"seconds": started.elapsed().as_secs_f64()});
        (mesh, colors, scene_up(run.scene()), info)
    } else if config.is_file() {
        bail!(
            "{}: meshes are exported from NeRF and IDR runs (this is neither)",
            run_dir.display()
        );
    } else {
        bail!("{} is not a run folder (no config.json)", run_dir.display());
    };
    if mesh.triangles.is_empty() {
        bail!(
            "{}: the surface is empty at this level (nothing to mesh)",
            run_dir.display()
        );
    }
    write_mesh(&mesh, &colors, up.to_array(), format, out)?;
    let summary = serde_json::json!({
        "mesh": out,
        "format": format!("{format:?}").to_lowercase(),
        "vertices": mesh.vertices.len(),
        "triangles": mesh.triangles.len(),
        "area": mesh.area(),
        "volume": mesh.volume(),
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
