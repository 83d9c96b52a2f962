//! What the commands share: the compute backend, the options of a training run, the one
//! generic `train` every variant's command calls, and small parsers.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use burn::prelude::Device;
use clap::Args;
use ins_core::backend::BackendChoice;
use ins_core::train::progress::FirstStep;
use ins_core::train::{TrainOptions, TrainOutcome};
use ins_models::run::Variant;

use crate::vgg_cmd::VggArgs;

/// Where a command computes.
#[derive(Args, Debug, Clone)]
pub struct DeviceArgs {
    /// Backend: auto (wgpu where a hardware GPU is present, else flex), flex or wgpu.
    #[arg(long, default_value = "auto")]
    pub backend: BackendChoice,
}

impl DeviceArgs {
    /// The device of the chosen backend (for wgpu, an error saying what to do when the machine
    /// has no adapter).
    pub fn device(&self) -> Result<Device> {
        Ok(self.backend.try_device()?)
    }
}

/// Options of every training command that are about the run, not the model.
#[derive(Args, Debug)]
pub struct RunArgs {
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

/// The parts of `ins-cli train <variant>` that every variant has.
pub struct TrainCommand<'a> {
    /// The run folder.
    pub out: &'a Path,
    /// Run options.
    pub run: &'a RunArgs,
    /// Backend.
    pub device: &'a DeviceArgs,
    /// VGG weights (loaded only where the run stylizes).
    pub vgg: &'a VggArgs,
}

impl TrainCommand<'_> {
    /// Trains `cfg` as a run of `V`: says what it starts (`what`, completed with the backend and
    /// the folder), prints the summary line, then where to look (`next`).
    pub fn train<V: Variant>(
        &self,
        cfg: &V::Config,
        checkpoint_every: usize,
        what: &str,
        next: &str,
    ) -> Result<TrainOutcome<V::Model>> {
        V::kind(cfg)?;
        let backend = self.device.backend.resolve();
        let device = backend.try_device()?;
        // A first wgpu run compiles and tunes kernels for minutes: say so until the first step.
        let first_step = ins_core::gpu::prepared().map(|r| {
            FirstStep::watch(
                &r.first_steps_note(),
                std::time::Duration::from_secs(20),
                self.run.quiet,
            )
        });
        let vgg = if V::style(cfg).styles.is_empty() {
            None
        } else {
            Some(self.vgg.load(&device)?)
        };
        eprintln!("{what} on {backend} into {}", self.out.display());
        let mut opts = self
            .run
            .train_options(self.out, V::seed(cfg), checkpoint_every);
        opts.first_step = first_step;
        let outcome = ins_models::run::train::<V>(cfg, vgg, &device, opts)?;
        print_summary(self.out, &outcome);
        eprintln!("done in {:.1} s: {next}", outcome.seconds);
        Ok(outcome)
    }
}

/// The one JSON line a finished `train` prints on stdout.
pub fn print_summary<M>(out: &Path, outcome: &TrainOutcome<M>) {
    let summary = serde_json::json!({
        "run": out,
        "steps": outcome.steps,
        "seconds": (outcome.seconds * 10.0).round() / 10.0,
        "last": outcome.last,
        "warnings": outcome.warnings,
    });
    println!("{summary}");
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
