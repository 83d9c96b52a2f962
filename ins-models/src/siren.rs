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
use ins_core::loss::LossWeights;
use ins_core::modules::cim::{SirenCim, SirenCimConfig};
use ins_core::modules::ins::Ins;
use ins_core::modules::sim::SimConfig;
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes};
use ins_core::train::{Phase, TrainOptions, TrainOutcome, Trainer};
use serde::{Deserialize, Serialize};
use vgg_import::Vgg;

use crate::image_task::{FIT, ImageTask, ImageTaskFor, PatchSpec, STYLIZE, render_image};

/// Everything that defines a SIREN+INS run; written to `config.json` in the run folder.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(default)]
pub struct SirenRunConfig {
    /// Content image.
    pub content: PathBuf,
    /// Style images (one-hot codes in this order).
    pub styles: Vec<PathBuf>,
    /// Longer side of the content at training time.
    pub size: usize,
    /// Longer side of the style images for their Gram targets.
    pub style_size: usize,
    /// Steps fitting the content.
    pub fit_steps: usize,
    /// Steps stylizing.
    pub stylize_steps: usize,
    /// Adam learning rate while fitting.
    pub lr_fit: f64,
    /// Adam learning rate while stylizing.
    pub lr_stylize: f64,
    /// Random pixels per fitting step.
    pub fit_batch: usize,
    /// Stylization patch: rays per side.
    pub patch: usize,
    /// Stylization patch stride (0: chosen so the patch spans the image).
    pub stride: usize,
    /// Width of the sine layers.
    pub hidden: usize,
    /// Number of sine layers.
    pub depth: usize,
    /// ω₀.
    pub omega0: f32,
    /// Width of the SIM.
    pub sim_hidden: usize,
    /// Loss weights; `None` takes the defaults for the VGG's preprocessing.
    pub weights: Option<LossWeights>,
    /// Seed.
    pub seed: u64,
    /// Steps between checkpoints.
    pub checkpoint_every: usize,
}

impl Default for SirenRunConfig {
    fn default() -> Self {
        Self {
            content: PathBuf::new(),
            styles: Vec::new(),
            size: 256,
            style_size: 128,
            fit_steps: 300,
            stylize_steps: 300,
            lr_fit: 1e-4,
            lr_stylize: 1e-4,
            fit_batch: 8192,
            patch: 128,
            stride: 0,
            hidden: 256,
            depth: 4,
            omega0: 30.0,
            sim_hidden: 64,
            weights: None,
            seed: 0,
            checkpoint_every: 100,
        }
    }
}

impl SirenRunConfig {
    /// Reads a JSON config (unknown fields are refused, missing ones take defaults).
    pub fn from_file(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}: malformed config", path.display()))
    }

    /// The model this config describes (fresh weights, seeded by `device.seed`).
    pub fn build_model(&self, device: &Device) -> Ins<SirenCim> {
        let cim = SirenCimConfig::new()
            .with_d_hidden(self.hidden)
            .with_depth(self.depth)
            .with_omega0(self.omega0)
            .init(device);
        let sim = SimConfig::new(self.styles.len().max(1)).with_d_hidden(self.sim_hidden);
        Ins::new(cim, &sim, true, device)
    }

    /// The stride that makes a `patch`-wide patch span the image (or the configured one).
    pub fn effective_stride(&self, w: usize, h: usize) -> usize {
        if self.stride > 0 {
            self.stride
        } else {
            (w.min(h) / self.patch.max(1)).max(1)
        }
    }

    /// The two phases.
    pub fn phases(&self, weights: LossWeights) -> Vec<Phase> {
        vec![
            Phase::new(FIT, self.fit_steps, self.lr_fit).weight("mse", 1.0),
            Phase::new(STYLIZE, self.stylize_steps, self.lr_stylize)
                .weight("style", weights.style)
                .weight("content", weights.content),
        ]
    }
}

/// Loads the content image at training size and the styles, naming files on error.
pub fn load_images(cfg: &SirenRunConfig) -> Result<(RgbImage, Vec<RgbImage>)> {
    if cfg.styles.is_empty() {
        bail!("at least one --style image is needed");
    }
    let content = RgbImage::load(&cfg.content)?.fit_within(cfg.size);
    if content.width < 16 || content.height < 16 {
        bail!(
            "{}: content is {}×{} at --size {}, too small (at least 16 px per side)",
            cfg.content.display(),
            content.width,
            content.height,
            cfg.size
        );
    }
    let styles = cfg
        .styles
        .iter()
        .map(|p| RgbImage::load(p))
        .collect::<Result<Vec<_>>>()?;
    Ok((content, styles))
}

/// Trains SIREN+INS into `opts.out_dir`; writes the config, the stylized images and a preview.
pub fn train(
    cfg: &SirenRunConfig,
    vgg: Vgg,
    device: &Device,
    opts: TrainOptions,
) -> Result<TrainOutcome<Ins<SirenCim>>> {
    let (content, styles) = load_images(cfg)?;
    let out = opts.out_dir.clone();
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let config_path = out.join("config.json");
    if opts.resume && config_path.exists() {
        let saved = SirenRunConfig::from_file(&config_path)?;
        if saved != *cfg {
            bail!(
                "{}: the run was started with another configuration; resume with the same options (or --config {})",
                config_path.display(),
                config_path.display()
            );
        }
    }
    ins_core::train::checkpoint::write_atomic(
        &config_path,
        serde_json::to_string_pretty(cfg)?.as_bytes(),
    )?;

    let weights = cfg
        .weights
        .unwrap_or_else(|| LossWeights::default_for(vgg.preprocess));
    let patch = PatchSpec {
        size: cfg.patch,
        stride: cfg.effective_stride(content.width, content.height),
    };
    let ad = device.clone().autodiff();
    let model = ins_core::train::seeding::seeded(&ad, cfg.seed, || cfg.build_model(&ad));
    let vgg = vgg.to_device(&ad);
    let mut task = ImageTask::new(
        content.clone(),
        &styles,
        cfg.style_size,
        vgg,
        cfg.fit_batch,
        patch,
        &ad,
    );
    let trainer = Trainer::new(cfg.phases(weights), opts);
    let outcome = trainer.run(&mut ImageTaskFor::<SirenCim>::new(&mut task), model)?;
    if outcome.finished {
        write_results(cfg, &outcome.model.valid(), &content, &styles, &out, device)?;
    }
    Ok(outcome)
}

/// Writes `stylized[_i].png` per style and `preview.png` (content | styles | results).
pub fn write_results(
    cfg: &SirenRunConfig,
    model: &Ins<SirenCim>,
    content: &RgbImage,
    styles: &[RgbImage],
    out: &Path,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let model = model.clone().to_device(device);
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
    let _ = cfg;
    Ok(paths)
}

/// A trained run loaded back for rendering.
pub struct SirenRun {
    /// Its configuration.
    pub config: SirenRunConfig,
    /// The model from the newest checkpoint.
    pub model: Ins<SirenCim>,
}

impl SirenRun {
    /// Loads `config.json` and the newest checkpoint of the run folder `dir`.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let config_path = dir.join("config.json");
        if !config_path.exists() {
            bail!(
                "{} is not a SIREN run folder (no config.json)",
                dir.display()
            );
        }
        let config = SirenRunConfig::from_file(&config_path)?;
        let store = CheckpointStore::new(dir.join("checkpoints"), 2);
        let ckpt = store
            .load_latest()?
            .with_context(|| format!("{}: no checkpoint in the run folder", dir.display()))?;
        let model = load_module_bytes(
            config.build_model(device),
            ckpt.model,
            &store.dir().join("latest"),
        )?;
        Ok(Self { config, model })
    }

    /// Renders at `w`×`h` with a style mix (normalised to sum 1).
    pub fn render(&self, w: usize, h: usize, mix: &[f32], device: &Device) -> Result<RgbImage> {
        let n = self.model.n_styles();
        if mix.len() != n {
            bail!("--mix has {} weights but the run has {n} styles", mix.len());
        }
        if mix.iter().any(|v| !v.is_finite() || *v < 0.0) {
            bail!("--mix weights must be non-negative numbers");
        }
        let sum: f32 = mix.iter().sum();
        if sum <= 0.0 {
            bail!("--mix weights sum to 0");
        }
        let code: Vec<f32> = mix.iter().map(|v| v / sum).collect();
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
