//! `vgg`: the 2D stylization step (`stylize2d`'s task) of a 256² image: VGG-16 to relu4_3,
//! Gram style loss and relu2_2 content loss, backward to the pixels, Adam.

use anyhow::Result;
use burn::prelude::*;
use ins_conv::Precision;
use ins_core::loss::LossWeights;
use ins_core::train::Phase;
use ins_models::stylize2d::{Canvas, Stylize2dObjective, Stylize2dTask};

use super::scenes::{random_painting, random_perceptual};
use super::{Timing, time_task};

pub fn run(device: &Device, steps: usize, precision: Precision) -> Result<Timing> {
    let perceptual = random_perceptual(device, precision)?;
    let content = random_painting(256, device)?;
    let mut task = Stylize2dTask::new(perceptual, &content);
    let w = LossWeights::default_for(
        vgg_import::Preprocess::Caffe,
        ins_core::loss::StyleLoss::Gram,
    );
    let phase = Phase::new("stylize", Stylize2dObjective::Stylize, steps + 1, 0.02)
        .weight("style", w.style)
        .weight("content", w.content);
    time_task(&mut task, Canvas::new(&content, device), phase, steps, None)
}
