//! `ins-cli export mesh`: a NeRF or IDR run's surface as PLY or binary glTF.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use ins_models::mesh_export::{MeshFormat, MeshFrame, export_mesh};
use ins_models::run::MeshOptions;

use crate::common::DeviceArgs;

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
    /// Coordinates: `scene` (the run's own: DTU's unit sphere, a capture recentred) or `world`
    /// (the dataset's, its cameras': DTU's millimetres, a COLMAP model's frame), to lay the mesh
    /// over the dataset's own points or ground truth.
    #[arg(long, value_enum, default_value_t = MeshFrame::Scene)]
    frame: MeshFrame,
    /// Output .ply or .glb.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn run(a: ExportMesh) -> Result<()> {
    let format = MeshFormat::choose(a.format, &a.out)?;
    let device = a.device.device()?;
    let options = MeshOptions {
        resolution: a.resolution,
        level: a.level,
    };
    let summary = export_mesh(
        &a.run,
        options,
        a.mix.as_deref(),
        format,
        a.frame,
        &a.out,
        &device,
    )?;
    println!("{summary}");
    Ok(())
}
