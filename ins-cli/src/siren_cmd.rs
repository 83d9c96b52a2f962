//! `ins-cli train siren` and `ins-cli render siren`.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use ins_core::backend::BackendChoice;
use ins_core::loss::LossWeights;
use ins_core::train::TrainOptions;
use ins_models::siren::{SirenRun, SirenRunConfig};
use vgg_import::load_vgg;

use crate::vgg_cmd::VggArgs;

#[derive(Subcommand, Debug)]
pub enum TrainVariant {
    /// SIREN + INS: fit an image, then stylize it (one or several styles).
    Siren(TrainSiren),
}

#[derive(Subcommand, Debug)]
pub enum RenderVariant {
    /// Render a SIREN + INS run at any size and style mix.
    Siren(RenderSiren),
}

#[derive(Args, Debug)]
pub struct TrainSiren {
    /// Content image (default: a built-in generated scene).
    #[arg(long)]
    content: Option<PathBuf>,
    /// Style image; repeat for a conditional multi-style model (default: a built-in generated painting).
    #[arg(long = "style")]
    styles: Vec<PathBuf>,
    /// Run folder (images, loss curve, metrics, config, checkpoints).
    #[arg(long, default_value = "runs/siren")]
    out: PathBuf,
    /// Total steps, split evenly between fitting and stylizing.
    #[arg(long)]
    steps: Option<usize>,
    /// Steps fitting the content (overrides --steps).
    #[arg(long)]
    fit_steps: Option<usize>,
    /// Steps stylizing (overrides --steps).
    #[arg(long)]
    stylize_steps: Option<usize>,
    /// Longer side of the content at training time, in pixels.
    #[arg(long)]
    size: Option<usize>,
    /// Style loss weight (default: per VGG preprocessing).
    #[arg(long)]
    style_weight: Option<f64>,
    /// Content loss weight (default: per VGG preprocessing).
    #[arg(long)]
    content_weight: Option<f64>,
    /// Backend: auto, flex, ndarray or wgpu.
    #[arg(long, default_value = "auto")]
    backend: BackendChoice,
    /// Seed.
    #[arg(long)]
    seed: Option<u64>,
    /// JSON config (fields of config.json); flags override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Continue the run in --out from its newest checkpoint.
    #[arg(long)]
    resume: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    #[command(flatten)]
    vgg: VggArgs,
}

#[derive(Args, Debug)]
pub struct RenderSiren {
    /// Run folder written by `train siren`.
    #[arg(long)]
    run: PathBuf,
    /// Style weights, comma-separated (default: the first style).
    #[arg(long, value_delimiter = ',')]
    mix: Option<Vec<f32>>,
    /// Output size WxH (default: the training size).
    #[arg(long)]
    size: Option<String>,
    /// Render an N-step interpolation strip from style 1 to style 2 instead.
    #[arg(long)]
    strip: Option<usize>,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// Backend.
    #[arg(long, default_value = "auto")]
    backend: BackendChoice,
}

pub fn train(variant: TrainVariant) -> Result<()> {
    let TrainVariant::Siren(a) = variant;
    let mut cfg = match &a.config {
        Some(p) => SirenRunConfig::from_file(p)?,
        None => SirenRunConfig::default(),
    };
    let inputs = a.out.join("inputs");
    match a.content {
        Some(c) => cfg.content = c,
        None if cfg.content.as_os_str().is_empty() => {
            let p = inputs.join("demo_content.png");
            if !p.exists() {
                ins_models::demo::demo_content(256).save(&p)?;
            }
            cfg.content = p;
        }
        None => {}
    }
    if !a.styles.is_empty() {
        cfg.styles = a.styles;
    } else if cfg.styles.is_empty() {
        let p = inputs.join("demo_style.png");
        if !p.exists() {
            ins_models::demo::demo_style(256).save(&p)?;
        }
        cfg.styles = vec![p];
    }
    if let Some(n) = a.steps {
        cfg.fit_steps = n / 2;
        cfg.stylize_steps = n - n / 2;
    }
    if let Some(n) = a.fit_steps {
        cfg.fit_steps = n;
    }
    if let Some(n) = a.stylize_steps {
        cfg.stylize_steps = n;
    }
    if let Some(s) = a.size {
        cfg.size = s;
    }
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    let backend = a.backend.resolve();
    let device = backend.device();
    let vgg = load_vgg(&a.vgg.source(), &device)?;
    if a.style_weight.is_some() || a.content_weight.is_some() {
        let d = cfg
            .weights
            .unwrap_or_else(|| LossWeights::default_for(vgg.preprocess));
        cfg.weights = Some(LossWeights {
            content: a.content_weight.unwrap_or(d.content),
            style: a.style_weight.unwrap_or(d.style),
        });
    }
    eprintln!(
        "training SIREN+INS on {backend} ({} style{}, VGG preprocessing {}) into {}",
        cfg.styles.len(),
        if cfg.styles.len() == 1 { "" } else { "s" },
        vgg.preprocess,
        a.out.display()
    );
    let mut opts = TrainOptions::new(&a.out);
    opts.seed = cfg.seed;
    opts.checkpoint_every = cfg.checkpoint_every;
    opts.resume = a.resume;
    opts.quiet = a.quiet;
    let outcome = ins_models::siren::train(&cfg, vgg, &device, opts)?;
    let summary = serde_json::json!({
        "run": a.out,
        "steps": outcome.steps,
        "seconds": (outcome.seconds * 10.0).round() / 10.0,
        "last": outcome.last,
    });
    println!("{summary}");
    eprintln!(
        "done in {:.1} s: see {}/preview.png, stylized*.png and loss_curve.png",
        outcome.seconds,
        a.out.display()
    );
    Ok(())
}

fn parse_size(s: &str) -> Result<(usize, usize)> {
    let parts: Vec<&str> = s.split(['x', 'X']).collect();
    if parts.len() != 2 {
        bail!("--size {s:?}: expected WxH, e.g. 512x512");
    }
    let w: usize = parts[0]
        .parse()
        .map_err(|_| anyhow::anyhow!("--size {s:?}: bad width"))?;
    let h: usize = parts[1]
        .parse()
        .map_err(|_| anyhow::anyhow!("--size {s:?}: bad height"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        bail!("--size {s:?}: each side must be between 1 and 16384");
    }
    Ok((w, h))
}

pub fn render(variant: RenderVariant) -> Result<()> {
    let RenderVariant::Siren(a) = variant;
    let device = a.backend.device();
    let run = SirenRun::load(&a.run, &device)?;
    let content = ins_core::imaging::RgbImage::load(&run.config.content)
        .map(|c| c.fit_within(run.config.size))
        .ok();
    let (w, h) = match &a.size {
        Some(s) => parse_size(s)?,
        None => content
            .map(|c| (c.width, c.height))
            .unwrap_or((run.config.size, run.config.size)),
    };
    let img = match a.strip {
        Some(n) => run.strip(w, h, n, &device)?,
        None => {
            let n = run.model.n_styles();
            let mix = a.mix.unwrap_or_else(|| {
                let mut m = vec![0.0; n];
                m[0] = 1.0;
                m
            });
            run.render(w, h, &mix, &device)?
        }
    };
    img.save(&a.out)?;
    println!("{}", a.out.display());
    Ok(())
}
