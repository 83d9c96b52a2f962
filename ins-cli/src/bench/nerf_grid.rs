//! `nerf-grid`: a pretraining step of `train nerf` with its defaults (hash-grid field, rays
//! marched through the occupancy grid), the grid holding a ball of radius 0.8 (about the share
//! of space a lego-like object fills) and not refreshed: volume rendering, MSE, backward, Adam.
//! The rays a step takes are the task's own choice, 2^17 samples over its running mean of
//! samples per ray; that mean starts at 64 and a ray here holds about 22, so the few timed
//! steps march about 2,300–2,600 rays, some 50–60 k samples, not yet the 2^17 a long run
//! settles to (`rays_per_s` says how many).

use anyhow::Result;
use burn::prelude::*;
use ins_core::loss::LossWeights;
use ins_core::train::RunFolder;
use ins_models::nerf::{Nerf, NerfRunConfig};
use ins_models::run::{RunKind, Start, Variant};
use ins_scene::geometry::Vec3;

use super::scenes::blender_scene;
use super::{Timing, time_task};

pub fn run(device: &Device, steps: usize) -> Result<Timing> {
    let (dir, data) = blender_scene(64, 8)?;
    let mut cfg = NerfRunConfig {
        eval_every: 0,
        occupancy_every: 0,
        ..Default::default()
    };
    cfg.schedule.steps = steps + 1;
    Nerf::resolve(&mut cfg, RunKind::Pretrain, &data);
    let model = Nerf::new_model(&cfg, &data, device);
    let folder = RunFolder::new(dir.path().join("run"));
    let mut task = Nerf::task(&cfg, Start::Fresh(data), None, &folder, device)?;
    if let Some(grid) = task.grid.as_mut() {
        grid.update(usize::MAX, 1, |p| {
            p.chunks_exact(3)
                .map(|q| {
                    if Vec3::new(q[0], q[1], q[2]).length() < 0.8 {
                        100.0
                    } else {
                        0.0
                    }
                })
                .collect()
        });
    }
    let w = LossWeights::default_for(
        vgg_import::Preprocess::Caffe,
        ins_core::loss::StyleLoss::Gram,
    );
    let phase = Nerf::phases(&cfg, RunKind::Pretrain, w).remove(0);
    time_task(&mut task, model, phase, steps, Some("rays"))
}
