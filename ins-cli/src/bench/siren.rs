//! `siren`: a SIREN+INS stylization step of `train siren` on a 128² image taken as one patch
//! (stride 1): the SIREN (4 sine layers of 256), SIM and AM for every pixel, VGG style and
//! content losses, backward, Adam.

use anyhow::Result;
use burn::prelude::*;
use ins_conv::Precision;
use ins_core::loss::LossWeights;
use ins_core::modules::cim::SirenCim;
use ins_models::image_task::ImageTask;
use ins_models::run::{RunKind, Variant};
use ins_models::siren::{Siren, SirenRunConfig};
use ins_scene::patches::PatchSpec;

use super::scenes::{random_painting, random_perceptual};
use super::{Timing, time_task};

const SIDE: usize = 128;

pub fn run(device: &Device, steps: usize, precision: Precision) -> Result<Timing> {
    let mut cfg = SirenRunConfig::default();
    cfg.style.styles = vec!["painting.png".into()];
    cfg.stylize_steps = steps + 1;
    let model = cfg.build_model(device);
    let content = random_painting(SIDE, device)?;
    let perceptual = random_perceptual(device, precision)?;
    let patch = PatchSpec::new(SIDE as u32, 1);
    let mut task = ImageTask::<SirenCim>::new(content, perceptual, cfg.fit_batch, patch, device)?;
    let w = LossWeights::default_for(
        vgg_import::Preprocess::Caffe,
        ins_core::loss::StyleLoss::Gram,
    );
    let stylize = Siren::phases(&cfg, RunKind::Pretrain, w).remove(1);
    time_task(&mut task, model, stylize, steps, None)
}
