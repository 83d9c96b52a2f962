//! `nerf-grid-stylize`: a stylization step of `train nerf --from RUN` with its defaults (the
//! hash-grid field frozen, SIM with its texture grid and AM trained; a 64×64 patch of rays
//! marched through an occupancy grid holding a shell between radii 0.3 and 0.8 (about 22 samples
//! a ray; lego's stylization marches 27–33); NNFM guided by the photo
//! within the default match radius; the geometry loss against the frozen teacher), backward,
//! Adam. The step users run most; VGG and the painting are random, as in `nerf-stylize`. The
//! field is fresh and nearly transparent, so no ray turns opaque: the samples behind a surface
//! that a real stylization leaves unshaded (lego: about 15 of 26 a ray) are all shaded here.

use anyhow::Result;
use burn::prelude::*;
use ins_conv::Precision;
use ins_core::loss::{LossWeights, PerceptualLoss, StyleLoss};
use ins_core::train::RunFolder;
use ins_models::nerf::run::fresh_grid;
use ins_models::nerf::{Nerf, NerfRunConfig};
use ins_models::run::{RunKind, Start, Variant};
use ins_scene::geometry::Vec3;

use super::scenes::{base_run, blender_scene, random_painting, random_vgg};
use super::{Timing, time_task};

pub fn run(device: &Device, steps: usize, precision: Precision) -> Result<Timing> {
    let (dir, data) = blender_scene(64, 8)?;
    let mut cfg = NerfRunConfig {
        eval_every: 0,
        occupancy_every: 0,
        ..Default::default()
    };
    cfg.source.from = Some(dir.path().join("base"));
    cfg.schedule.steps = steps + 1;
    cfg.style.styles = vec!["painting.png".into()];
    Nerf::resolve(&mut cfg, RunKind::Stylize, &data);
    let pretrained = Nerf::new_model(&cfg, &data, device);
    let model = Nerf::add_stylizer(pretrained.clone(), &cfg, 1, device);
    // The pretrained run's occupancy grid (its checkpoint's extra state): a thick shell.
    let mut grid = fresh_grid(&data.scene, cfg.occupancy_resolution);
    grid.update(usize::MAX, 1, |p| {
        p.chunks_exact(3)
            .map(|q| {
                let r = Vec3::new(q[0], q[1], q[2]).length();
                if (0.3..0.8).contains(&r) { 100.0 } else { 0.0 }
            })
            .collect()
    });
    let base = base_run(dir.path(), &cfg, data, pretrained, Some(grid));
    let perceptual = PerceptualLoss::new(
        random_vgg(device, precision),
        &[random_painting(256, device)?],
        cfg.style.style_size,
        cfg.style.loss(),
        device,
    )
    .with_match_radius(cfg.style.match_radius)
    .with_texture_match_radius(cfg.style.texture_match_radius);
    let folder = RunFolder::new(dir.path().join("run"));
    let mut task = Nerf::task(&cfg, Start::From(base), Some(perceptual), &folder, device)?;
    let w = LossWeights::default_for(vgg_import::Preprocess::Caffe, StyleLoss::Nnfm);
    let phase = Nerf::phases(&cfg, RunKind::Stylize, w).remove(0);
    time_task(&mut task, model, phase, steps, None)
}
