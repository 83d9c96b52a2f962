//! Classic 2D style transfer (Gatys et al., CVPR 2016): optimise the pixels of one image so that
//! its VGG Gram matrices match the painting's while its relu2_2 features stay the content's.
//!
//! It uses the same VGG, the same losses and the same weight convention as the stylizing
//! variants, so it is both a product feature (`ins-cli stylize2d`) and the per-view baseline
//! that stylized 3D representations are measured against: each frame stylized on its own knows
//! nothing of its neighbours.

use std::path::{Path, PathBuf};

use anyhow::Result;
use burn::module::Param;
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{ContentTarget, LossWeights, PerceptualLoss, StyleLoss};
use ins_core::train::{
    GroupSpec, LossTerms, Optimizable, Phase, StepContext, Task, TrainOptions, TrainOutcome,
    Trainer,
};
use serde::{Deserialize, Serialize};
use vgg_import::Vgg;

/// The optimised image: its pixels are the parameters, `[1, 3, H, W]`, read through a clamp to
/// [0, 1] (a pixel pushed out of range stops moving further out).
#[derive(Module, Debug)]
pub struct Canvas {
    /// Pixels, starting as the content image.
    pub pixels: Param<Tensor<4>>,
}

impl Optimizable for Canvas {
    fn groups(&self) -> Vec<GroupSpec> {
        vec![GroupSpec::new("pixels", &["pixels"])]
    }
}

impl Canvas {
    /// A canvas holding `image`.
    pub fn new(image: &RgbImage, device: &Device) -> Self {
        Self {
            pixels: Param::from_tensor(image.to_tensor(device)),
        }
    }

    /// The image, `[1, 3, H, W]` in [0, 1].
    pub fn image(&self) -> Tensor<4> {
        self.pixels.val().clamp(0.0, 1.0)
    }

    /// The image as an [`RgbImage`].
    pub fn to_rgb(&self) -> Result<RgbImage> {
        RgbImage::from_hwc(self.image().detach().squeeze_dim::<3>(0).permute([1, 2, 0]))
    }
}

/// What the one phase of a 2D stylization computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stylize2dObjective {
    /// Gram style loss to the painting and relu2_2 content loss to the content image.
    Stylize,
}

/// Settings of one 2D stylization.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stylize2dSettings {
    /// Optimisation steps.
    pub steps: usize,
    /// Adam learning rate, in pixel units (colours in [0, 1]).
    pub lr: f64,
    /// Style and content weights.
    pub weights: LossWeights,
    /// Longer side of the painting for its style targets.
    pub style_size: usize,
    /// How the painting's style is matched.
    pub style_loss: StyleLoss,
    /// NNFM's matches guided by the photo within this radius (see `StyleArgs::match_radius`).
    pub match_radius: Option<f32>,
}

/// The task: fixed targets, one image to optimise.
pub struct Stylize2dTask {
    perceptual: PerceptualLoss,
    content: ContentTarget,
}

/// The painting's loss on the autodiff device the optimisation runs on: its targets are
/// computed once and shared by every frame of a per-frame run (a VGG pass over the painting
/// per frame would cost as much as a step).
pub fn painting_loss(
    vgg: &Vgg,
    style: &RgbImage,
    settings: &Stylize2dSettings,
    device: &Device,
) -> PerceptualLoss {
    let ad = device.clone().autodiff();
    PerceptualLoss::new(
        vgg.to_device(&ad),
        std::slice::from_ref(style),
        settings.style_size,
        settings.style_loss,
        &ad,
    )
    .with_match_radius(settings.match_radius)
}

impl Stylize2dTask {
    /// The task of stylizing `content` with the painting of `perceptual` (on the autodiff
    /// device the optimisation runs on).
    pub fn new(perceptual: PerceptualLoss, content: &RgbImage) -> Self {
        let device = perceptual.codes.device();
        let content = perceptual.content_target(content.to_tensor(&device));
        Self {
            perceptual,
            content,
        }
    }
}

impl Task for Stylize2dTask {
    type Model = Canvas;
    type Objective = Stylize2dObjective;

    fn terms(&self, _objective: Stylize2dObjective) -> &'static [&'static str] {
        &["style", "content"]
    }

    fn losses(
        &mut self,
        model: &Canvas,
        _step: &StepContext<Stylize2dObjective>,
    ) -> Result<LossTerms> {
        let (style, content) = self.perceptual.terms(model.image(), &self.content);
        Ok(LossTerms::default()
            .term("style", style)
            .term("content", content))
    }
}

/// Stylizes `content` with `style` through the trainer (progress, metrics and checkpoints in
/// `opts.out_dir`); returns the image and the trainer's outcome.
pub fn stylize(
    content: &RgbImage,
    style: &RgbImage,
    vgg: Vgg,
    settings: &Stylize2dSettings,
    opts: TrainOptions,
    device: &Device,
) -> Result<(RgbImage, TrainOutcome<Canvas>)> {
    let perceptual = painting_loss(&vgg, style, settings, device);
    stylize_with(content, &perceptual, settings, opts)
}

/// [`stylize`] against a painting's loss built beforehand ([`painting_loss`];
/// `settings.style_size` is its), on the loss's device.
pub fn stylize_with(
    content: &RgbImage,
    perceptual: &PerceptualLoss,
    settings: &Stylize2dSettings,
    opts: TrainOptions,
) -> Result<(RgbImage, TrainOutcome<Canvas>)> {
    let ad = perceptual.codes.device();
    let mut task = Stylize2dTask::new(perceptual.clone(), content);
    let phase = Phase::new(
        "stylize",
        Stylize2dObjective::Stylize,
        settings.steps,
        settings.lr,
    )
    .weight("style", settings.weights.style)
    .weight("content", settings.weights.content);
    let outcome = Trainer::new(vec![phase], opts).run(&mut task, Canvas::new(content, &ad))?;
    let image = outcome.model.to_rgb()?;
    Ok((image, outcome))
}

/// `<out>.run`: where the trainer's metrics, plot and checkpoints of a 2D stylization written
/// to `out` go.
pub fn frame_run_dir(out: &Path) -> PathBuf {
    let mut s = out.as_os_str().to_owned();
    s.push(".run");
    PathBuf::from(s)
}

/// What every frame of a per-frame 2D stylization shares.
pub struct FrameRun<'a> {
    /// The painting.
    pub style: &'a RgbImage,
    /// VGG-16.
    pub vgg: &'a Vgg,
    /// Steps, learning rate, weights.
    pub settings: &'a Stylize2dSettings,
    /// No progress bars.
    pub quiet: bool,
    /// Keep each frame's metrics and loss curve in `<frame>.png.run/`.
    pub keep_runs: bool,
    /// Where to compute.
    pub device: &'a Device,
}

/// Stylizes each of `frames` on its own into `out/<stem>.png`; frames already there are kept,
/// so an interrupted run continues where it stopped.
pub fn stylize_frames(
    frames: &[PathBuf],
    out_dir: &Path,
    load: impl Fn(&Path) -> Result<RgbImage>,
    run: &FrameRun,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir).map_err(|e| anyhow::anyhow!("{}: {e}", out_dir.display()))?;
    let mut written = Vec::with_capacity(frames.len());
    let perceptual = painting_loss(run.vgg, run.style, run.settings, run.device);
    for (i, frame) in frames.iter().enumerate() {
        let name = frame.file_stem().unwrap_or_default().to_string_lossy();
        let out = out_dir.join(format!("{name}.png"));
        written.push(out.clone());
        if out.exists() {
            eprintln!(
                "frame {}/{}: {} exists, kept",
                i + 1,
                frames.len(),
                out.display()
            );
            continue;
        }
        eprintln!("frame {}/{}: {}", i + 1, frames.len(), frame.display());
        let img = load(frame)?;
        // One frame is minutes at most: no checkpoints, the finished frames are the progress
        // an interrupted run keeps.
        let mut opts = TrainOptions::new(frame_run_dir(&out));
        opts.checkpoint_every = 0;
        opts.quiet = run.quiet;
        let (result, _) = stylize_with(&img, &perceptual, run.settings, opts)?;
        result.save(&out)?;
        if run.keep_runs {
            let _ = std::fs::remove_dir_all(frame_run_dir(&out).join("checkpoints"));
        } else {
            let _ = std::fs::remove_dir_all(frame_run_dir(&out));
        }
    }
    Ok(written)
}
