//! SIREN + INS: stylizing an image through its implicit representation.
//!
//! CIM = SIREN sine layers over (x, y) ∈ [−1, 1]²; SIM = small MLP over the style code; AM =
//! identity-start blend; head = linear → sigmoid RGB. Phase "fit" reconstructs the content with
//! pixel MSE; phase "stylize" trains all modules with VGG style + content losses on strided
//! patches, every style of the batch at once.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, PerceptualLoss, StyleLoss};
use ins_core::modules::cim::{SirenCim, SirenCimConfig};
use ins_core::modules::ins::Ins;
use ins_core::modules::sim::SimConfig;
use ins_core::train::{Phase, RunFolder};
use ins_scene::patches::PatchSpec;
use serde::{Deserialize, Serialize};

use crate::image_task::{ImageObjective, ImageTask, render_image};
use crate::run::{FinalScores, Run, RunConfig, RunKind, Start, StyleArgs, Variant};

/// Everything that defines a SIREN+INS run: the `ins-cli train siren` flags and the fields of
/// the run's `config.json` are this one struct (unknown fields in a `--config` file are refused).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct SirenRunConfig {
    /// Content image (default: a built-in generated scene).
    #[arg(long)]
    pub content: Option<PathBuf>,
    /// Paintings and the perceptual loss (default painting: a built-in one).
    #[command(flatten)]
    #[serde(flatten)]
    pub style: StyleArgs,
    /// Longer side of the content at training time, in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Steps fitting the content. On the demo, 150 steps at 2e-4 end the stylization within
    /// 2 % of the losses of 300 at 1e-4 (content +1.9 %, style −0.7 %) in 2:17 instead of ~6 min.
    #[arg(long, default_value_t = 150)]
    pub fit_steps: usize,
    /// Steps stylizing.
    #[arg(long, default_value_t = 150)]
    pub stylize_steps: usize,
    /// Adam learning rate while fitting.
    #[arg(long, default_value_t = 2e-4)]
    pub lr_fit: f64,
    /// Adam learning rate while stylizing.
    #[arg(long, default_value_t = 2e-4)]
    pub lr_stylize: f64,
    /// Random pixels per fitting step.
    #[arg(long, default_value_t = 8192)]
    pub fit_batch: usize,
    /// Width of the sine layers.
    #[arg(long, default_value_t = 256)]
    pub hidden: usize,
    /// Number of sine layers.
    #[arg(long, default_value_t = 4)]
    pub depth: usize,
    /// SIREN's ω₀.
    #[arg(long, default_value_t = 30.0)]
    pub omega0: f32,
    /// Width of the SIM.
    #[arg(long, default_value_t = 64)]
    pub sim_hidden: usize,
    /// Seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Steps between checkpoints.
    #[arg(long, default_value_t = 100)]
    pub checkpoint_every: usize,
}

impl Default for SirenRunConfig {
    fn default() -> Self {
        crate::config::clap_defaults()
    }
}

impl RunConfig for SirenRunConfig {
    fn style(&self) -> &StyleArgs {
        &self.style
    }

    fn seed(&self) -> u64 {
        self.seed
    }
}

impl SirenRunConfig {
    /// Reads a JSON config (unknown fields are refused, missing ones take defaults).
    pub fn from_file(path: &Path) -> Result<Self> {
        crate::config::read_json(path)
    }

    /// The content image path (set by the caller before training).
    pub fn content_path(&self) -> Result<&Path> {
        self.content
            .as_deref()
            .context("no content image: pass --content FILE")
    }

    /// The model this config describes (fresh weights, seeded by `device.seed`).
    pub fn build_model(&self, device: &Device) -> Ins<SirenCim> {
        let cim = SirenCimConfig::new()
            .with_d_hidden(self.hidden)
            .with_depth(self.depth)
            .with_omega0(self.omega0)
            .init(device);
        let sim = SimConfig::new(self.style.styles.len().max(1)).with_d_hidden(self.sim_hidden);
        Ins::new(cim, &sim, true, device)
    }

    /// The two phases. Fitting trains the content path (CIM and RGB head) with SIM and AM
    /// frozen, so the AM is still the identity when stylization starts; stylizing trains all.
    pub fn phases(&self, weights: LossWeights) -> Vec<Phase<ImageObjective>> {
        vec![
            Phase::new("fit", ImageObjective::Fit, self.fit_steps, self.lr_fit)
                .weight("mse", 1.0)
                .freeze("sim")
                .freeze("am"),
            Phase::new(
                "stylize",
                ImageObjective::Stylize,
                self.stylize_steps,
                self.lr_stylize,
            )
            .weight("style", weights.style)
            .weight("content", weights.content),
        ]
    }
}

/// The images of a SIREN run: the content at training size and the paintings.
pub struct SirenImages {
    /// The content, its longer side at `--size`.
    pub content: RgbImage,
    /// The paintings, in the order of their codes.
    pub styles: Vec<RgbImage>,
}

/// Share of the content's shorter side a stylization patch spans: all of it.
pub const PATCH_SHARE: f32 = 1.0;

/// Loads the content image at training size and the styles, naming files on error.
pub fn load_images(cfg: &SirenRunConfig) -> Result<SirenImages> {
    if cfg.style.styles.is_empty() {
        bail!("at least one --style image is needed");
    }
    let content = RgbImage::load(cfg.content_path()?)?.fit_within(cfg.size);
    if content.width < 16 || content.height < 16 {
        bail!(
            "{}: content is {}×{} at --size {}, too small (at least 16 px per side)",
            cfg.content_path()?.display(),
            content.width,
            content.height,
            cfg.size
        );
    }
    let styles = cfg
        .style
        .styles
        .iter()
        .map(|p| RgbImage::load(p))
        .collect::<Result<Vec<_>>>()?;
    Ok(SirenImages { content, styles })
}

/// SIREN + INS: one run fits the image, then stylizes it.
pub struct Siren;

/// A SIREN run folder loaded back.
pub type SirenRun = Run<Siren>;

impl Variant for Siren {
    const NAME: &'static str = "SIREN";
    const KEY: &'static str = "siren";
    type Config = SirenRunConfig;
    type Data = SirenImages;
    type Model = Ins<SirenCim>;
    type Objective = ImageObjective;
    type Task = ImageTask<SirenCim>;
    type Extra = ();

    /// A SIREN run fits and stylizes in one go: always a pretraining run, with its paintings.
    fn kind(cfg: &SirenRunConfig) -> Result<RunKind> {
        if cfg.style.styles.is_empty() {
            bail!("at least one --style image is needed");
        }
        Ok(RunKind::Pretrain)
    }

    fn load_data(cfg: &mut SirenRunConfig) -> Result<SirenImages> {
        load_images(cfg)
    }

    fn palette(data: &SirenImages, max: usize) -> Vec<[f32; 3]> {
        let stride = (data.content.data.len() / 3 / max.max(1)).max(1);
        data.content
            .data
            .chunks_exact(3)
            .step_by(stride)
            .map(|c| [c[0], c[1], c[2]])
            .collect()
    }

    fn resolve(cfg: &mut SirenRunConfig, _kind: RunKind, _data: &SirenImages) {
        cfg.style.resolve(128, 128, StyleLoss::Gram);
    }

    fn inherit(_cfg: &mut SirenRunConfig, _base: &SirenRunConfig, from: &Path) -> Result<()> {
        bail!(
            "--from {}: a SIREN run fits and stylizes in one run; train it again with other --style images",
            from.display()
        )
    }

    fn new_model(cfg: &SirenRunConfig, _data: &SirenImages, device: &Device) -> Ins<SirenCim> {
        cfg.build_model(device)
    }

    fn add_stylizer(
        model: Ins<SirenCim>,
        _cfg: &SirenRunConfig,
        _n_styles: usize,
        _device: &Device,
    ) -> Ins<SirenCim> {
        model
    }

    fn task(
        cfg: &SirenRunConfig,
        start: Start<Siren>,
        style: Option<PerceptualLoss>,
        _folder: &RunFolder,
        device: &Device,
    ) -> Result<ImageTask<SirenCim>> {
        let Start::Fresh(images) = start else {
            bail!("a SIREN run has no base run");
        };
        let perceptual = style.context("a SIREN run needs its paintings' loss")?;
        let (w, h) = (images.content.width as u32, images.content.height as u32);
        let patch = PatchSpec::spanning(
            cfg.style.patch as u32,
            cfg.style.stride as u32,
            PATCH_SHARE,
            w,
            h,
        )?;
        ImageTask::new(images.content, perceptual, cfg.fit_batch, patch, device)
    }

    fn phases(
        cfg: &SirenRunConfig,
        _kind: RunKind,
        weights: LossWeights,
    ) -> Vec<Phase<ImageObjective>> {
        cfg.phases(weights)
    }

    fn final_report(
        model: &Ins<SirenCim>,
        _task: &ImageTask<SirenCim>,
        cfg: &SirenRunConfig,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<FinalScores> {
        let images = load_images(cfg)?;
        write_results(&model.valid(), &images, folder.dir(), device)?;
        Ok(FinalScores::new())
    }
}

/// Writes `stylized[_i].png` per style and `preview.png` (content | styles | results).
pub fn write_results(
    model: &Ins<SirenCim>,
    images: &SirenImages,
    out: &Path,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let model = model.clone().to_device(device);
    let (content, styles) = (&images.content, &images.styles);
    let n = styles.len();
    let mut paths = Vec::new();
    let mut row = vec![content.clone()];
    let mut results = Vec::new();
    for i in 0..n {
        let mut code = vec![0.0; n];
        code[i] = 1.0;
        let img = render_image(&model, content.width, content.height, &code, device)?;
        let p = if n == 1 {
            out.join("stylized.png")
        } else {
            out.join(format!("stylized_{i}.png"))
        };
        img.save(&p)?;
        paths.push(p);
        results.push(img);
    }
    for s in styles {
        row.push(
            s.resized(
                (s.width as f64 * content.height as f64 / s.height as f64)
                    .round()
                    .max(1.0) as usize,
                content.height,
            ),
        );
    }
    row.extend(results);
    RgbImage::hstack(&row).save(&out.join("preview.png"))?;
    Ok(paths)
}

impl Run<Siren> {
    /// The content's size at training time.
    pub fn training_size(&self) -> (usize, usize) {
        (self.data.content.width, self.data.content.height)
    }

    /// Renders at `w`×`h` with a style mix (normalised to sum 1).
    pub fn render(&self, w: usize, h: usize, mix: &[f32], device: &Device) -> Result<RgbImage> {
        let code = crate::style_mix::normalized(self.model.n_styles(), Some(mix))?;
        render_image(&self.model, w, h, &code, device)
    }

    /// `steps` renders interpolating from style 1 to style 2, side by side.
    pub fn strip(&self, w: usize, h: usize, steps: usize, device: &Device) -> Result<RgbImage> {
        let n = self.model.n_styles();
        if n < 2 {
            bail!("--strip needs a run with at least two styles (this one has {n})");
        }
        let steps = steps.max(2);
        let mut imgs = Vec::new();
        for i in 0..steps {
            let t = i as f32 / (steps - 1) as f32;
            let mut mix = vec![0.0; n];
            mix[0] = 1.0 - t;
            mix[1] = t;
            imgs.push(render_image(&self.model, w, h, &mix, device)?);
        }
        Ok(RgbImage::hstack(&imgs))
    }
}
