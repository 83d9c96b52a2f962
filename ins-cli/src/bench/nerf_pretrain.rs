//! `nerf-pretrain`: a pretraining step of `train nerf --cim mlp` (the paper's NeRF): 1024 rays,
//! the coarse network on 64 stratified samples, the fine one on those and 64 importance
//! samples, volume rendering, MSE of both renders, backward, Adam.

use anyhow::Result;
use burn::prelude::*;
use ins_core::loss::LossWeights;
use ins_core::modules::field::CimKind;
use ins_core::train::RunFolder;
use ins_models::nerf::{Nerf, NerfRunConfig};
use ins_models::run::{RunKind, Start, Variant};

use super::scenes::blender_scene;
use super::{Timing, time_task};

/// The paper's configuration, 64 + 64 samples, no evaluation while timing.
pub fn mlp_config() -> NerfRunConfig {
    NerfRunConfig {
        cim: CimKind::Mlp,
        rays: 1024,
        coarse_samples: 64,
        fine_samples: 64,
        eval_every: 0,
        ..Default::default()
    }
}

pub fn run(device: &Device, steps: usize) -> Result<Timing> {
    let (dir, data) = blender_scene(64, 8)?;
    let mut cfg = mlp_config();
    cfg.schedule.steps = steps + 1;
    Nerf::resolve(&mut cfg, RunKind::Pretrain, &data);
    let model = Nerf::new_model(&cfg, &data, device);
    let folder = RunFolder::new(dir.path().join("run"));
    let mut task = Nerf::task(&cfg, Start::Fresh(data), None, &folder, device)?;
    let w = LossWeights::default_for(
        vgg_import::Preprocess::Caffe,
        ins_core::loss::StyleLoss::Gram,
    );
    let phase = Nerf::phases(&cfg, RunKind::Pretrain, w).remove(0);
    time_task(&mut task, model, phase, steps, Some("rays"))
}
