//! `ins-cli eval mesh`: a NeRF or IDR run's surface against a reference surface (DTU's
//! ground-truth points, or the `reference.ply` that `data synth --format dtu` writes).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use ins_models::mesh_score::{MeshScoreOptions, score_mesh};
use ins_models::run::MeshOptions;

use crate::common::DeviceArgs;

#[derive(Args, Debug)]
pub struct EvalMesh {
    /// Run folder written by `train nerf` or `train idr`.
    #[arg(long)]
    run: PathBuf,
    /// PLY point cloud or mesh of the true surface, in the dataset's world frame (its
    /// cameras'): DTU's `stl0NN_total.ply`, or a synthesized scene's `reference.ply`.
    #[arg(long)]
    reference: PathBuf,
    /// Samples along the longest side of the grid marching cubes runs on (as `export mesh`).
    #[arg(long, default_value_t = 256)]
    resolution: usize,
    /// NeRF: the density of the surface (default: the run's own, as `export mesh`).
    #[arg(long)]
    level: Option<f32>,
    /// Points drawn over the mesh.
    #[arg(long, default_value_t = 200_000)]
    samples: usize,
    /// Distance (the reference's units) beyond which a point is an outlier, not averaged
    /// (default: a tenth of the unit sphere's radius; DTU's benchmark caps at 20 mm).
    #[arg(long)]
    max_distance: Option<f64>,
    /// Distance (the reference's units) precision and recall count within (default: a
    /// hundredth of the unit sphere's radius).
    #[arg(long)]
    threshold: Option<f64>,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn run(a: EvalMesh) -> Result<()> {
    let device = a.device.device()?;
    let options = MeshScoreOptions {
        mesh: MeshOptions {
            resolution: a.resolution,
            level: a.level,
        },
        samples: a.samples,
        max_distance: a.max_distance,
        threshold: a.threshold,
    };
    let score = score_mesh(&a.run, &a.reference, &options, &device)?;
    println!("{}", serde_json::to_string(&score)?);
    Ok(())
}
