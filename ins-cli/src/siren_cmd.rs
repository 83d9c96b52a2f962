//! `ins-cli train siren` and `ins-cli render siren`.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{ArgMatches, Args};
use ins_models::siren::{Siren, SirenRun, SirenRunConfig};

use crate::common::{DeviceArgs, RunArgs, TrainCommand, VggArgs, merged_config, parse_size};

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
    device: DeviceArgs,
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
    #[command(flatten)]
    device: DeviceArgs,
}

/// Writes a built-in demo input once (atomically, so a killed run never leaves half of one).
fn demo_input(
    dir: &Path,
    name: &str,
    make: impl FnOnce() -> ins_core::imaging::RgbImage,
) -> Result<PathBuf> {
    let p = dir.join(name);
    if !p.exists() {
        make().save(&p)?;
    }
    Ok(p)
}

pub fn train(a: TrainSiren, matches: &ArgMatches) -> Result<()> {
    let mut cfg = merged_config::<Siren>(a.config, matches, a.run.config.as_deref())?;
    // The backend before anything is written: a machine that cannot run it is told so with
    // the run folder untouched.
    a.device.device()?;
    let inputs = a.out.join("inputs");
    if cfg.content.is_none() {
        cfg.content = Some(demo_input(&inputs, "demo_content.png", || {
            ins_models::demo::demo_content(256)
        })?);
    }
    if cfg.style.styles.is_empty() {
        cfg.style.styles = vec![demo_input(
            &inputs,
            "bridgewater_madonna.png",
            ins_models::demo::demo_painting,
        )?];
    }
    if let Some(n) = a.steps {
        cfg.fit_steps = n / 2;
        cfg.stylize_steps = n - n / 2;
    }
    let n = cfg.style.styles.len();
    let what = format!(
        "training SIREN+INS ({n} style{})",
        if n == 1 { "" } else { "s" }
    );
    let next = format!(
        "see {}/preview.png, stylized*.png and loss_curve.png",
        a.out.display()
    );
    let cmd = TrainCommand {
        out: &a.out,
        run: &a.run,
        device: &a.device,
        vgg: &a.vgg,
    };
    cmd.train::<Siren>(&cfg, cfg.checkpoint_every, &what, &next)?;
    Ok(())
}

pub fn render(a: RenderSiren) -> Result<()> {
    let device = a.device.device()?;
    let run = SirenRun::load(&a.run, &device)?;
    let (w, h) = match &a.size {
        Some(s) => parse_size(s)?,
        None => run.training_size(),
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
