//! `ins-cli bench idr-pretrain`: one IDR pretraining step with `train idr`'s defaults, on a
//! synthetic DTU scene at 400×300 (the size of scan37 in the README): sphere tracing of the
//! rays, the differentiable surface point, colour, mask and eikonal losses, backward, Adam.

use anyhow::{Context, Result};
use burn::optim::GradientsParams;
use burn::prelude::*;
use ins_core::data::synthetic::{SynthOptions, write_dtu};
use ins_core::train::{StepContext, Task};
use ins_models::idr::config::{IdrKind, IdrRunConfig};
use ins_models::idr::model::IdrModel;
use ins_models::idr::run::{load_scene, pretrain_phase, pretrain_task};

use crate::bench::timed;

/// Rays of an `idr-pretrain` step (`train idr`'s default).
pub fn rays() -> usize {
    IdrRunConfig::default().rays
}

/// Times `steps` pretraining steps; the scene is written to a temporary folder first.
pub fn bench_idr_pretrain(device: &Device, steps: usize) -> Result<Vec<f64>> {
    let mut cfg = IdrRunConfig::default();
    cfg.steps = cfg.steps_for(IdrKind::Pretrain);
    cfg.lr = cfg.lr_for(IdrKind::Pretrain);
    let dir = tempfile::tempdir().context("a temporary folder for the synthetic scene")?;
    write_dtu(
        dir.path(),
        &SynthOptions {
            size: 400,
            views: 8,
        },
    )?;
    let (scene, _) = load_scene(dir.path(), 1, 0, false)?;
    let mut task = pretrain_task(&cfg, scene, Vec::new(), dir.path().join("val"), device)?;
    let phase = pretrain_phase(&cfg);
    let mut model = Some(IdrModel::new(&cfg.arch(), device));
    let mut adam = ins_core::train::adam();
    let mut step = 0;
    timed(steps, || {
        let m = model.take().context("model")?;
        let ctx = StepContext {
            phase: &phase,
            step_in_phase: step,
            global_step: step,
            seed: step as u64,
        };
        step += 1;
        let loss = task
            .losses(&m, &ctx)?
            .terms
            .into_iter()
            .map(|(name, t)| t.mul_scalar(phase.weight_of(name)))
            .reduce(|a, b| a + b)
            .context("no loss terms")?;
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        let m = adam.step(cfg.lr, m, grads);
        // Wait for the update to land before the clock stops.
        let _ = m
            .sdf
            .sdf(Tensor::<2>::zeros([1, 3], device))
            .into_scalar::<f32>();
        model = Some(m);
        Ok(())
    })
}
