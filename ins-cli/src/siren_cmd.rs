//! `ins-cli train siren` and `ins-cli render siren`.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{ArgMatches, Args};
use ins_core::backend::BackendChoice;
use ins_core::train::TrainOptions;
use ins_models::config::merge_with_file;
use ins_models::siren::{SirenRun, SirenRunConfig};

use crate::vgg_cmd::VggArgs;

/// Options of every training command that are about the run, not the model.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Backend: auto, flex, ndarray or wgpu.
    #[arg(long, default_value = "auto")]
    pub backend: BackendChoice,
    /// JSON config (fields of a run's config.json); flags given on the command line override it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Continue the run in --out from its newest checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

impl RunArgs {
    /// The trainer's options for a run into `out` with the config's seed and checkpoint interval.
    pub fn train_options(&self, out: &Path, seed: u64, checkpoint_every: usize) -> TrainOptions {
        let mut opts = TrainOptions::new(out);
        opts.seed = seed;
        opts.checkpoint_every = checkpoint_every;
        opts.resume = self.resume;
        opts.quiet = self.quiet;
        opts
    }
}

/// The one JSON line a finished `train` prints on stdout.
pub fn print_summary<M>(out: &Path, outcome: &ins_core::train::TrainOutcome<M>) {
    let summary = serde_json::json!({
        "run": out,
        "steps": outcome.steps,
        "seconds": (outcome.seconds * 10.0).round() / 10.0,
        "last": outcome.last,
    });
    println!("{summary}");
}

#[derive(Args, Debug)]
pub struct TrainSiren {
    /// Run folder (images, loss curve, metrics, config, checkpoints).
    #[arg(long, default_value = "runs/siren")]
    out: PathBuf,
    /// Total steps, split evenly between fitting and stylizing (overrides both).
    #[arg(long)]
    steps: Option<usize>,
    #[command(flatten)]
    config: SirenRunConfig,
    #[command(flatten)]
    run: RunArgs,
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

/// Writes a generated demo input once (atomically, so a killed run never leaves half of one).
fn demo_input(
    dir: &Path,
    name: &str,
    make: fn(usize) -> ins_core::imaging::RgbImage,
) -> Result<PathBuf> {
    let p = dir.join(name);
    if !p.exists() {
        make(256).save(&p)?;
    }
    Ok(p)
}

pub fn train(a: TrainSiren, matches: &ArgMatches) -> Result<()> {
    let mut cfg = merge_with_file(a.config, matches, a.run.config.as_deref())?;
    let inputs = a.out.join("inputs");
    if cfg.content.is_none() {
        cfg.content = Some(demo_input(
            &inputs,
            "demo_content.png",
            ins_models::demo::demo_content,
        )?);
    }
    if cfg.styles.is_empty() {
        cfg.styles = vec![demo_input(
            &inputs,
            "demo_style.png",
            ins_models::demo::demo_style,
        )?];
    }
    if let Some(n) = a.steps {
        cfg.fit_steps = n / 2;
        cfg.stylize_steps = n - n / 2;
    }
    let backend = a.run.backend.resolve();
    let device = backend.device();
    let vgg = a.vgg.load(&device)?;
    eprintln!(
        "training SIREN+INS on {backend} ({} style{}, VGG preprocessing {}) into {}",
        cfg.styles.len(),
        if cfg.styles.len() == 1 { "" } else { "s" },
        vgg.preprocess,
        a.out.display()
    );
    let opts = a.run.train_options(&a.out, cfg.seed, cfg.checkpoint_every);
    let outcome = ins_models::siren::train(&cfg, vgg, &device, opts)?;
    print_summary(&a.out, &outcome);
    eprintln!(
        "done in {:.1} s: see {}/preview.png, stylized*.png and loss_curve.png",
        outcome.seconds,
        a.out.display()
    );
    Ok(())
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> Result<(usize, usize)> {
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

pub fn render(a: RenderSiren) -> Result<()> {
    let device = a.backend.device();
    let run = SirenRun::load(&a.run, &device)?;
    let content = run
        .config
        .content
        .as_deref()
        .and_then(|p| ins_core::imaging::RgbImage::load(p).ok())
        .map(|c| c.fit_within(run.config.size));
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
