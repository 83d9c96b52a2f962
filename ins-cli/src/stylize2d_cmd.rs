//! `ins-cli stylize2d`: classic 2D style transfer of one image, or of every frame of a folder
//! independently (the per-view baseline of the consistency evaluation).

use std::path::{Path, PathBuf};

use crate::common::DeviceArgs;
use anyhow::{Result, bail};
use clap::Args;
use ins_core::imaging::RgbImage;
use ins_core::loss::LossWeights;
use ins_core::train::TrainOptions;
use ins_models::stylize2d::{FrameRun, Stylize2dSettings, frame_run_dir, stylize, stylize_frames};
use ins_scene::data::images::list_images;
use vgg_import::Vgg;

use crate::common::VggArgs;

#[derive(Args, Debug)]
pub struct Stylize2d {
    /// Content image (PNG or JPEG).
    #[arg(long, required_unless_present = "frames", conflicts_with = "frames")]
    content: Option<PathBuf>,
    /// Stylize every image of this folder on its own instead (`--out` is then a folder; frames
    /// already there are kept, so an interrupted run continues where it stopped).
    #[arg(long, value_name = "DIR")]
    frames: Option<PathBuf>,
    /// Painting whose style to transfer.
    #[arg(long)]
    style: PathBuf,
    /// Output PNG (a folder with --frames). Metrics and the loss curve go beside it, in
    /// `<out>.run/`.
    #[arg(long)]
    out: PathBuf,
    /// Optimisation steps.
    #[arg(long, default_value_t = 200)]
    steps: usize,
    /// Longer side of the content at most, in pixels (larger images are scaled down; 0: their
    /// own size).
    #[arg(long, default_value_t = 256)]
    size: usize,
    /// Longer side of the painting for its style targets.
    #[arg(long, default_value_t = 256)]
    style_size: usize,
    /// How the painting's style is matched: gram (Gatys), nnfm (ARF's nearest-neighbour
    /// feature matching) or mean-std.
    #[arg(long, default_value = "gram")]
    style_loss: ins_core::loss::StyleLoss,
    /// With nnfm: each position may only match painting features within this cosine of the
    /// photo's best match there (0: a style swap; unset or 2: plain NNFM).
    #[arg(long)]
    match_radius: Option<f32>,
    /// Adam learning rate in pixel units.
    #[arg(long, default_value_t = 0.02)]
    lr: f64,
    /// Style loss weight (default: per VGG preprocessing, as for every variant).
    #[arg(long)]
    style_weight: Option<f64>,
    /// Content loss weight (default: per VGG preprocessing).
    #[arg(long)]
    content_weight: Option<f64>,
    #[command(flatten)]
    device: DeviceArgs,
    /// Continue a single-image run from its newest checkpoint.
    #[arg(long)]
    resume: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    #[command(flatten)]
    vgg: VggArgs,
}

impl Stylize2d {
    fn settings(&self, vgg: &Vgg) -> Stylize2dSettings {
        Stylize2dSettings {
            steps: self.steps,
            lr: self.lr,
            weights: LossWeights::or_defaults(
                vgg.preprocess,
                self.style_loss,
                self.content_weight,
                self.style_weight,
            ),
            style_size: self.style_size,
            style_loss: self.style_loss,
            match_radius: self.match_radius,
        }
    }

    fn load_content(&self, path: &Path) -> Result<RgbImage> {
        let img = RgbImage::load(path)?;
        let img = if self.size > 0 && img.width.max(img.height) > self.size {
            img.fit_within(self.size)
        } else {
            img
        };
        if img.width < 16 || img.height < 16 {
            bail!(
                "{}: {}×{} at --size {} is too small for VGG (at least 16 px per side)",
                path.display(),
                img.width,
                img.height,
                self.size
            );
        }
        Ok(img)
    }
}

pub fn run(a: Stylize2d) -> Result<()> {
    if a.steps == 0 {
        bail!("--steps must be at least 1");
    }
    let style = RgbImage::load(&a.style)?;
    let backend = a.device.backend.resolve();
    let device = backend.try_device()?;
    let vgg = a.vgg.load(&device)?;
    let settings = a.settings(&vgg);
    let options = |out: &Path, resume: bool, checkpoint_every: usize| {
        let mut o = TrainOptions::new(frame_run_dir(out));
        o.checkpoint_every = checkpoint_every;
        o.resume = resume;
        o.quiet = a.quiet;
        o
    };
    match (&a.content, &a.frames) {
        (Some(content), _) => {
            let img = a.load_content(content)?;
            eprintln!(
                "stylizing {} ({}×{}) with {} on {backend}, {} steps",
                content.display(),
                img.width,
                img.height,
                a.style.display(),
                a.steps
            );
            let opts = options(&a.out, a.resume, 100);
            let (result, outcome) = stylize(&img, &style, vgg, &settings, opts, &device)?;
            result.save(&a.out)?;
            crate::common::print_summary(&a.out, &outcome);
        }
        (None, Some(dir)) => {
            let frames = list_images(dir)?;
            if frames.is_empty() {
                bail!("{}: no PNG or JPEG images in this folder", dir.display());
            }
            let started = std::time::Instant::now();
            let load = |p: &Path| a.load_content(p);
            let each = FrameRun {
                style: &style,
                vgg: &vgg,
                settings: &settings,
                quiet: a.quiet,
                keep_runs: true,
                device: &device,
            };
            stylize_frames(&frames, &a.out, load, &each)?;
            println!(
                "{}",
                serde_json::json!({
                    "frames": frames.len(),
                    "out": a.out,
                    "seconds": (started.elapsed().as_secs_f64() * 10.0).round() / 10.0,
                })
            );
        }
        (None, None) => bail!("give --content IMAGE or --frames DIR"),
    }
    Ok(())
}
