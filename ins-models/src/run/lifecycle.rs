//! A run's life, once for every variant: [`train`] pretrains on a scene or stylizes a
//! pretrained run into a locked run folder, and [`Run::load`] loads a run folder back.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::backend::DispatchDevice;
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, PerceptualLoss};
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes, module_bytes};
use ins_core::train::{Phase, RunFolder, RunLock, TrainError, TrainOptions, TrainOutcome, Trainer};
use vgg_import::{Preprocess, Vgg};

use super::args::RunKind;
use super::variant::{RunConfig, RunState, Start, Variant};

/// Trains a run of variant `V` into `opts.out_dir`: pretraining (`--scene`, or SIREN's image),
/// or stylizing the pretrained run the config names (`--from`). `vgg` is needed where the run
/// stylizes.
///
/// Every input (data, base run, paintings) is read before the folder is touched, so bad input
/// leaves nothing behind; then the folder is locked (a second run given the same folder is
/// refused), a folder that already holds a run is refused unless resuming, and only then is
/// `config.json` written.
pub fn train<V: Variant>(
    cfg: &V::Config,
    vgg: Option<Vgg>,
    device: &Device,
    opts: TrainOptions,
) -> Result<TrainOutcome<V::Model>> {
    let Prepared {
        cfg,
        model,
        mut task,
        phases,
        folder,
        lock: _lock,
    } = prepare::<V>(cfg, vgg, device, &opts)?;
    let final_pictures = opts.final_pictures;
    let mut outcome = Trainer::new(phases, opts).run(&mut task, model)?;
    if outcome.finished && final_pictures {
        outcome.final_scores = V::final_report(&outcome.model, &task, &cfg, &folder, device)?;
        if !outcome.final_scores.is_empty() {
            let path = folder.final_scores();
            let json = serde_json::to_string_pretty(&outcome.final_scores)?;
            ins_io::write_atomic(&path, json.as_bytes())?;
        }
    }
    Ok(outcome)
}

/// A run ready for its first step: the folder locked and its `config.json` written, the
/// config resolved, the model (drawn or loaded), the task and the phases built.
pub struct Prepared<V: Variant> {
    /// The resolved configuration (as written to `config.json`).
    pub cfg: V::Config,
    /// The model on the autodiff device, before any step.
    pub model: V::Model,
    /// The training task.
    pub task: V::Task,
    /// The run's phases, in order.
    pub phases: Vec<Phase<V::Objective>>,
    /// The run folder.
    pub folder: RunFolder,
    /// Held until the run ends: a second run given the same folder is refused meanwhile.
    pub lock: RunLock,
}

/// Everything [`train`] does before its first step, exactly as it does it: what tests compare
/// a step of on two backends, with the run's own initial parameters, paintings' loss and
/// phases.
pub fn prepare<V: Variant>(
    cfg: &V::Config,
    vgg: Option<Vgg>,
    device: &Device,
    opts: &TrainOptions,
) -> Result<Prepared<V>> {
    let kind = V::kind(cfg)?;
    let mut cfg = cfg.clone();
    let start = match kind {
        RunKind::Pretrain => {
            let data = V::load_data(&mut cfg)?;
            V::resolve(&mut cfg, kind, &data);
            Start::Fresh(data)
        }
        RunKind::Stylize => {
            let from = cfg
                .base_run()
                .context("stylizing needs --from RUN")?
                .to_path_buf();
            let base = Run::<V>::load(&from, device)?;
            if base.base.is_some() {
                bail!(
                    "{} is already a stylized run; stylize its pretrained run ({}) instead",
                    from.display(),
                    base.config
                        .base_run()
                        .map_or("?".into(), |p| p.display().to_string())
                );
            }
            V::inherit(&mut cfg, &base.config, &from)?;
            V::resolve(&mut cfg, kind, &base.data);
            Start::From(base)
        }
    };
    let styles = load_styles(&cfg.style().styles)?;

    let folder = RunFolder::new(&opts.out_dir);
    let lock = folder.lock()?;
    if !opts.resume && folder.checkpoints().is_started() {
        return Err(TrainError::RunExists {
            dir: folder.dir().to_path_buf(),
        }
        .into());
    }
    crate::config::write_run_config(&cfg, V::KEY, folder.dir(), opts.resume)?;

    let ad = device.clone().autodiff();
    let seed = cfg.seed();
    let build = |d: &Device| match &start {
        Start::Fresh(data) => {
            ins_core::train::seeding::seeded(d, seed, || V::new_model(&cfg, data, d))
        }
        Start::From(base) => ins_core::train::seeding::seeded(d, seed, || {
            V::add_stylizer(base.model.clone().to_device(d), &cfg, styles.len(), d)
        }),
    };
    let mut model = build(&ad);
    // Each backend has its own random generator: off the CPU, the new parameters are drawn on
    // flex and copied in, so that a seed gives the same model on wgpu as on flex and their runs
    // can be compared step by step.
    if !matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Flex(_)
    ) {
        let drawn = module_bytes(&build(&Device::flex().autodiff()))?;
        model = load_module_bytes(model, drawn, Path::new("the initial parameters"))?;
    }
    let (style, preprocess) = if styles.is_empty() {
        (None, Preprocess::Caffe)
    } else {
        let vgg = vgg.context("stylizing needs VGG-16")?.to_device(&ad);
        let preprocess = vgg.preprocess;
        let s = cfg.style();
        let mut loss = PerceptualLoss::new(vgg, &styles, s.style_size, s.loss(), &ad)
            .with_match_radius(s.match_radius)
            .with_texture_match_radius(s.texture_match_radius);
        if s.color_transfer {
            let data = match &start {
                Start::Fresh(data) => data,
                Start::From(base) => &base.data,
            };
            loss = loss.with_color_transfer(&V::palette(data, PALETTE_SAMPLE), &styles);
        }
        (Some(loss), preprocess)
    };
    let s = cfg.style();
    let weights = LossWeights::or_defaults(preprocess, s.loss(), s.content_weight, s.style_weight);
    let task = V::task(&cfg, start, style, &folder, &ad)?;
    let phases = V::phases(&cfg, kind, weights);
    Ok(Prepared {
        cfg,
        model,
        task,
        phases,
        folder,
        lock,
    })
}

/// Colours of the training photos sampled for colour transfer.
const PALETTE_SAMPLE: usize = 65536;

/// The paintings, each read now so a missing or damaged one stops the run before it starts.
fn load_styles(paths: &[PathBuf]) -> Result<Vec<RgbImage>> {
    paths.iter().map(|p| RgbImage::load(p)).collect()
}

/// "an" before a name read with a vowel first (IDR), "a" otherwise (NeRF, SIREN).
fn article(name: &str) -> &'static str {
    if name.starts_with(['A', 'E', 'I', 'O', 'U']) {
        "an"
    } else {
        "a"
    }
}

/// A run folder loaded back: its configuration, data, model and extra state.
pub struct Run<V: Variant> {
    /// The run folder.
    pub dir: PathBuf,
    /// Its configuration.
    pub config: V::Config,
    /// The pretrained run's configuration, for a stylized run.
    pub base: Option<V::Config>,
    /// The data at the run's resolution.
    pub data: V::Data,
    /// The model of the newest checkpoint.
    pub model: V::Model,
    /// What the checkpoint keeps beside the model.
    pub extra: V::Extra,
}

impl<V: Variant> Run<V> {
    /// Loads `dir` (a folder written by `train`) on `device`.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let folder = RunFolder::new(dir);
        let config_path = folder.config();
        if !config_path.is_file() {
            bail!(
                "{} is not {} {} run folder (no config.json)",
                dir.display(),
                article(V::NAME),
                V::NAME
            );
        }
        let not_this = || {
            format!(
                "{} is not {} {} run",
                dir.display(),
                article(V::NAME),
                V::NAME
            )
        };
        crate::config::check_variant(&config_path, V::KEY).with_context(not_this)?;
        let config: V::Config = crate::config::read_json(&config_path).with_context(not_this)?;
        let base: Option<V::Config> = match V::kind(&config)? {
            RunKind::Pretrain => None,
            RunKind::Stylize => {
                let from = config.base_run().context("a stylized run without --from")?;
                Some(
                    crate::config::read_json(&RunFolder::new(from).config())
                        .with_context(|| format!("the base run of {}", dir.display()))?,
                )
            }
        };
        let mut scene_cfg = base.clone().unwrap_or_else(|| config.clone());
        let data = V::load_data(&mut scene_cfg)?;
        let field_run = match config.base_run() {
            Some(from) if base.is_some() => RunFolder::new(from),
            _ => RunFolder::new(dir),
        };
        V::check_data(&data, &field_run)?;
        let latest = folder
            .checkpoints()
            .latest_dir()?
            .with_context(|| format!("{}: no checkpoint in the run folder", dir.display()))?;
        let ckpt = CheckpointStore::load_dir(&latest)?;
        let mut model = V::new_model(&scene_cfg, &data, device);
        if base.is_some() {
            model = V::add_stylizer(model, &config, config.style().styles.len(), device);
        }
        let model = load_module_bytes(model, ckpt.model, &CheckpointStore::model_file(&latest))?;
        let extra = V::Extra::decode(ckpt.task.as_deref(), &CheckpointStore::task_file(&latest))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            config,
            base,
            data,
            model,
            extra,
        })
    }

    /// The configuration that defines the data and the content module: the base run's for a
    /// stylized run.
    pub fn scene_config(&self) -> &V::Config {
        self.base.as_ref().unwrap_or(&self.config)
    }

    /// A style code `[1, n]` from mix weights (normalised; default: the first style), or `None`
    /// for an unstylized run (where a mix is an error naming the run). A run renders as many
    /// styles as its config names paintings (its stylizer was built for them).
    pub fn code(&self, mix: Option<&[f32]>, device: &Device) -> Result<Option<Tensor<2>>> {
        let n_styles = self.config.style().styles.len();
        crate::style_mix::code(n_styles, mix, &self.dir, device)
    }
}
