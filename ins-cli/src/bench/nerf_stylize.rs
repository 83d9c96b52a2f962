//! `nerf-stylize`: a stylization step of `train nerf --cim mlp --from RUN`: a 32×32 patch of
//! rays (stride 1), the frozen coarse network, the fine network with SIM (4 layers of 256, the
//! code at each, 10 octaves of position) and AM, VGG style and content losses of the patch, the
//! geometry loss against the frozen teacher at the same points, backward, Adam.

use anyhow::Result;
use burn::prelude::*;
use ins_conv::Precision;
use ins_core::loss::LossWeights;
use ins_core::train::RunFolder;
use ins_models::nerf::Nerf;
use ins_models::run::{RunKind, Start, Variant};

use super::nerf_pretrain::mlp_config;
use super::scenes::{base_run, blender_scene, random_perceptual};
use super::{Timing, time_task};

pub fn run(device: &Device, steps: usize, precision: Precision) -> Result<Timing> {
    let (dir, data) = blender_scene(64, 8)?;
    let mut cfg = mlp_config();
    cfg.source.from = Some(dir.path().join("base"));
    cfg.schedule.steps = steps + 1;
    cfg.style.styles = vec!["painting.png".into()];
    cfg.style.patch = 32;
    cfg.style.stride = 1;
    cfg.stylizer.position_freqs = 10;
    // The benchmark's workload (docs/benchmarks.md) is the paper's: Gram, no texture grid.
    cfg.stylizer.sim_grid = 0;
    cfg.style.style_loss = Some(ins_core::loss::StyleLoss::Gram);
    // The paper's (and PyTorch reference's) step trains the density too, under the geometry
    // loss; the product's default keeps the density and needs no teacher pass.
    cfg.stylize_density = true;
    Nerf::resolve(&mut cfg, RunKind::Stylize, &data);
    let pretrained = Nerf::new_model(&cfg, &data, device);
    let model = Nerf::add_stylizer(pretrained.clone(), &cfg, 1, device);
    let base = base_run(dir.path(), &cfg, data, pretrained, None);
    let perceptual = random_perceptual(device, precision)?;
    let folder = RunFolder::new(dir.path().join("run"));
    let mut task = Nerf::task(&cfg, Start::From(base), Some(perceptual), &folder, device)?;
    let w = LossWeights::default_for(
        vgg_import::Preprocess::Caffe,
        ins_core::loss::StyleLoss::Gram,
    );
    let phase = Nerf::phases(&cfg, RunKind::Stylize, w).remove(0);
    time_task(&mut task, model, phase, steps, None)
}
