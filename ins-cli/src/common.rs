//! What the commands share: the compute backend, the VGG weights, the options of a training
//! run, the one generic `train` every variant's command calls, and small parsers.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::Device;
use clap::{ArgMatches, Args};
use ins_conv::Precision;
use ins_core::backend::BackendChoice;
use ins_core::train::progress::FirstStep;
use ins_core::train::{TrainOptions, TrainOutcome};
use ins_models::run::{RunConfig, Variant};
use vgg_import::{Preprocess, Vgg, VggSource, load_vgg};

/// Where a command computes.
#[derive(Args, Debug, Clone)]
pub struct DeviceArgs {
    /// Backend: auto (wgpu where a hardware GPU is present, else flex), flex, wgpu, or cuda
    /// (an NVIDIA GPU through CUDA; needs the driver, NVRTC and CUDA's headers: CUDA_PATH).
    #[arg(long, default_value = "auto")]
    pub backend: BackendChoice,
}

impl DeviceArgs {
    /// The device of the chosen backend (for wgpu and CUDA, an error saying what to do when the
    /// machine has no adapter, driver or CUDA compiler).
    pub fn device(&self) -> Result<Device> {
        Ok(self.backend.try_device()?)
    }
}

/// Where VGG weights come from; shared by every command that needs them.
#[derive(Args, Debug, Clone)]
pub struct VggArgs {
    /// VGG-16 ONNX file (default: the cached ImageNet VGG-16, fetched on first use).
    #[arg(long, value_name = "FILE")]
    pub onnx: Option<PathBuf>,
    /// Input convention of the weights: caffe or torch (default: detected from the file).
    #[arg(long, value_name = "P")]
    pub preprocess: Option<Preprocess>,
    /// Cache folder (default: $INS_CACHE_DIR, else ~/.cache/ins-rs).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Arithmetic of the VGG convolutions: f32; bf16 (BF16 products with f32 sums on Intel AMX
    /// or by AVX-512 BF16, on flex; f32 on CPUs with neither); or f16 (Burn's convolution in
    /// half precision on a GPU: CUDA, or a wgpu adapter with f16 shaders; f32 elsewhere). Default: bf16 where
    /// the CPU has either, else f32. f32 also keeps the dense products of a NeRF field and of
    /// SIREN's hidden layers in f32 (bf16 by default where the CPU has AVX-512 BF16).
    #[arg(long, value_name = "P")]
    pub precision: Option<Precision>,
}

impl VggArgs {
    /// The precision these arguments ask for, the default resolved for this CPU.
    pub fn precision(&self) -> Precision {
        self.precision.unwrap_or(Precision::Bf16.effective())
    }

    /// `--precision f32` keeps the dense products of a NeRF field and of SIREN's hidden layers
    /// in f32 too (else bf16 where the CPU has AVX-512 BF16), on this thread for the rest of
    /// the command.
    pub fn apply_to_products(&self) {
        if self.precision == Some(Precision::F32) {
            std::mem::forget(ins_core::kernels::dense_bf16::forbid());
        }
    }

    /// Loads the VGG these arguments describe, at the asked precision (saying so when BF16 was
    /// asked for and this CPU cannot run it).
    pub fn load(&self, device: &Device) -> anyhow::Result<Vgg> {
        self.apply_to_products();
        let vgg = load_vgg(&self.source(), device)?;
        let precision = self.precision();
        let runs = precision.effective_on(device);
        match (precision, runs) {
            (Precision::Bf16, Precision::F32) if ins_conv::kernel_device(device) => eprintln!(
                "--precision bf16: this CPU (or {}) offers neither AMX-BF16 nor AVX-512 BF16; \
                 VGG runs in f32",
                ins_conv::dpbf16::DISABLE_ENV
            ),
            (Precision::Bf16, Precision::F32) => eprintln!(
                "VGG convolutions in f32 (Burn's convolution: the BF16 kernels are flex's; \
                 --precision f16 for half precision on a GPU)"
            ),
            (Precision::F16, Precision::F32) => eprintln!(
                "--precision f16: this device has no f16 arithmetic (f16 runs on CUDA and on a \
                 wgpu adapter with f16 shaders); VGG runs in f32"
            ),
            (_, Precision::Bf16) => eprintln!(
                "VGG convolutions in {} (--precision f32 for f32)",
                ins_conv::Engine::bf16_or_f32().describe()
            ),
            (_, Precision::F16) => {
                eprintln!("VGG convolutions in f16 on the GPU (--precision f32 for f32)")
            }
            (_, Precision::F32) => {}
        }
        Ok(vgg.with_precision(precision))
    }

    /// The source description, fetching the default weights if needed.
    pub fn source(&self) -> VggSource {
        VggSource {
            onnx: self.onnx.clone(),
            preprocess: self.preprocess,
            cache_dir: self.cache.clone(),
            fetch_if_missing: true,
        }
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
    /// The held-out views rendered once more at the end (`ins-cli stylize` leaves them out:
    /// its report shows the views along the camera path).
    #[arg(skip = true)]
    pub final_pictures: bool,
}

impl RunArgs {
    /// The trainer's options for a run into `out` with the config's seed and checkpoint interval.
    pub fn train_options(&self, out: &Path, seed: u64, checkpoint_every: usize) -> TrainOptions {
        let mut opts = TrainOptions::new(out);
        opts.seed = seed;
        opts.checkpoint_every = checkpoint_every;
        opts.resume = self.resume;
        opts.quiet = self.quiet;
        opts.final_pictures = self.final_pictures;
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
        self.vgg.apply_to_products();
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
        let vgg = if cfg.style().styles.is_empty() {
            None
        } else {
            Some(self.vgg.load(&device)?)
        };
        eprintln!("{what} on {backend} into {}", self.out.display());
        let mut opts = self
            .run
            .train_options(self.out, cfg.seed(), checkpoint_every);
        opts.first_step = first_step;
        let outcome = ins_models::run::train::<V>(cfg, vgg, &device, opts)?;
        print_summary(self.out, &outcome);
        if let Some(line) = final_scores_line(&outcome.final_scores) {
            eprintln!("{line}");
        }
        eprintln!("done in {:.1} s: {next}", outcome.seconds);
        Ok(outcome)
    }
}

/// A variant's configuration: the flags given on the command line over the `--config FILE`
/// (a run's `config.json` or one written by hand), over the defaults. A file another variant's
/// run wrote is refused by name.
pub fn merged_config<V: Variant>(
    cli: V::Config,
    matches: &ArgMatches,
    file: Option<&Path>,
) -> Result<V::Config> {
    if let Some(file) = file {
        ins_models::config::check_variant(file, V::KEY)
            .with_context(|| format!("--config is not for `ins-cli train {}`", V::KEY))?;
    }
    ins_models::config::merge_with_file(cli, matches, file)
}

/// The one JSON line a finished `train` prints on stdout: with `final`, the scores of the
/// held-out views rendered at the end (also in the run's `val/final.json`).
pub fn print_summary<M>(out: &Path, outcome: &TrainOutcome<M>) {
    let mut summary = serde_json::json!({
        "run": out,
        "steps": outcome.steps,
        "seconds": (outcome.seconds * 10.0).round() / 10.0,
        "last": outcome.last,
        "warnings": outcome.warnings,
    });
    if !outcome.final_scores.is_empty() {
        summary["final"] = serde_json::json!(outcome.final_scores);
    }
    println!("{summary}");
}

/// The final scores for a reader: `held out (7 views): iou 0.9843, psnr_mask 20.94 dB, …`.
fn final_scores_line(scores: &std::collections::BTreeMap<String, f64>) -> Option<String> {
    let views = scores.get("views")?;
    let terms: Vec<String> = scores
        .iter()
        .filter(|(k, _)| k.as_str() != "views")
        .map(|(k, v)| match k.as_str() {
            k if k.starts_with("psnr") => format!("{k} {v:.2} dB"),
            k => format!("{k} {v:.4}"),
        })
        .collect();
    Some(format!("held out ({views} views): {}", terms.join(", ")))
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
