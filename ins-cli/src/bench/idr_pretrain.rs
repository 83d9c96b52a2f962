//! `ins-cli bench idr-pretrain`: one IDR pretraining step with `train idr`'s defaults, on a
//! synthetic DTU scene at 400×300 (the size of scan37 in the README): the SDF rendered as a
//! volume (the coarse pass, the samples near the surface with their gradients and colours),
//! colour, mask, eikonal and smoothness terms, backward, Adam. (Before the thirtieth session
//! the default, and so this bench, was the sphere-traced surface.)

use anyhow::{Context, Result};
use burn::prelude::*;
use ins_core::loss::LossWeights;
use ins_models::idr::config::IdrRunConfig;
use ins_models::idr::run::{Idr, load_scene, pretrain_task};
use ins_models::run::{RunKind, Variant};
use ins_scene::data::synthetic::{SynthOptions, write_dtu};

use super::{Timing, time_task};

/// Times `steps` pretraining steps; the scene is written to a temporary folder first.
pub fn run(device: &Device, steps: usize) -> Result<Timing> {
    let dir = tempfile::tempdir().context("a temporary folder for the synthetic scene")?;
    write_dtu(
        dir.path(),
        &SynthOptions {
            size: 400,
            views: 8,
        },
    )?;
    let (scene, _) = load_scene(dir.path(), 1, None, 0, false)?;
    let mut cfg = IdrRunConfig::default();
    Idr::resolve(&mut cfg, RunKind::Pretrain, &scene);
    let rays = cfg.rays_for() as f64;
    let mut task = pretrain_task(&cfg, scene, Vec::new(), dir.path().join("val"), device)?;
    let model = Idr::new_model(&cfg, &task.scene, device);
    let w = LossWeights::default_for(
        vgg_import::Preprocess::Caffe,
        ins_core::loss::StyleLoss::Gram,
    );
    let phase = Idr::phases(&cfg, RunKind::Pretrain, w).remove(0);
    let mut timing = time_task(&mut task, model, phase, steps, None)?;
    timing.rays = Some(rays);
    Ok(timing)
}
