//! IDR runs end to end: pretraining a surface on a masked multi-view scene, stylizing it, and
//! loading a run folder back.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::data::{LoadOptions, Scene, SceneFormat, Split, detect_format};
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, StyleTarget};
use ins_core::render::patches::PatchSpec;
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes};
use ins_core::train::{LrSchedule, Phase, TrainOptions, TrainOutcome, Trainer};
use vgg_import::Vgg;

use super::config::{IdrKind, IdrRunConfig};
use super::eval::{evaluate_views, save_pictures};
use super::model::IdrModel;
use super::task::{IdrObjective, IdrTask, SurfaceStylization};
use crate::image_task::one_hot_codes;
use crate::nerf::config::auto_downscale;

/// Loads a DTU/IDR scene for surface reconstruction: the format must be DTU (unit-sphere frame
/// and masks), masks must exist unless `no_mask`, and every `holdout`-th view goes to val.
pub fn load_scene(
    path: &Path,
    downscale: u32,
    holdout: usize,
    no_mask: bool,
) -> Result<(Scene, u32)> {
    let format = detect_format(path)?;
    if format != SceneFormat::Dtu {
        bail!(
            "{}: IDR reconstructs surfaces from DTU/IDR scenes (cameras.npz with a unit-sphere scale_mat, image/, mask/); this is a {format} scene — train a NeRF on it instead (`ins-cli train nerf`)",
            path.display()
        );
    }
    let factor = if downscale == 0 {
        let probe = Scene::load(path, &LoadOptions::default())?;
        let (w, h) = probe.resolution();
        auto_downscale(w, h, 512)
    } else {
        downscale
    };
    let mut scene = Scene::load(
        path,
        &LoadOptions {
            downscale: factor,
            ..Default::default()
        },
    )?;
    if !no_mask && !scene.views.iter().all(|v| v.mask.is_some()) {
        bail!(
            "{}: IDR needs an object mask per view (mask/ folder); pass --no-mask to train without them (colour only on the whole image, a weaker surface)",
            path.display()
        );
    }
    if holdout > 0 {
        let all: Vec<usize> = (0..scene.views.len()).collect();
        scene.val = all.iter().copied().filter(|i| i % holdout == 0).collect();
        scene.train = all.into_iter().filter(|i| i % holdout != 0).collect();
    }
    if scene.split(Split::Train).is_empty() {
        bail!("{}: the scene has no training views", path.display());
    }
    Ok((scene, factor))
}

/// Pretrains a surface on `cfg.scene` into `opts.out_dir`.
pub fn pretrain(
    cfg: &IdrRunConfig,
    device: &Device,
    opts: TrainOptions,
) -> Result<TrainOutcome<IdrModel>> {
    let scene_path = cfg.scene.clone().context("pretraining needs --scene DIR")?;
    cfg.arch().validate().map_err(anyhow::Error::msg)?;
    if !(0.0..=1.0).contains(&cfg.mask_rays) {
        bail!(
            "--mask-rays {}: the share of rays inside the masks is from 0 to 1",
            cfg.mask_rays
        );
    }
    if !(cfg.lr_decay > 0.0 && cfg.lr_decay <= 1.0) {
        bail!(
            "--lr-decay {}: the final learning rate is a fraction of the first, above 0 and at most 1",
            cfg.lr_decay
        );
    }
    let (scene, factor) = load_scene(&scene_path, cfg.downscale, cfg.holdout, cfg.no_mask)?;
    let mut cfg = cfg.clone();
    cfg.downscale = factor;
    cfg.steps = cfg.steps_for(IdrKind::Pretrain);
    cfg.lr = cfg.lr_for(IdrKind::Pretrain);
    let out = opts.out_dir.clone();
    crate::config::write_run_config(&cfg, &out, opts.resume)?;
    let ad = device.clone().autodiff();
    let model = ins_core::train::seeding::seeded(&ad, cfg.seed, || IdrModel::new(&cfg.arch(), &ad));
    let views = scene.split(Split::Val).to_vec();
    let mut task = pretrain_task(&cfg, scene, views, out.join("val"), &ad)?;
    let phase = pretrain_phase(&cfg);
    let outcome = Trainer::new(vec![phase], opts).run(&mut task, model)?;
    if outcome.finished {
        final_pictures(&outcome.model, &task, &out, device)?;
    }
    Ok(outcome)
}

/// The pretraining task of `cfg` (steps resolved) on `scene`: its rays, masks and eikonal
/// points, scoring `views` every `cfg.eval_every` steps into `val_dir`.
pub fn pretrain_task(
    cfg: &IdrRunConfig,
    scene: Scene,
    views: Vec<usize>,
    val_dir: PathBuf,
    device: &Device,
) -> Result<IdrTask> {
    let mut task = IdrTask::new(
        scene,
        cfg.rays,
        cfg.steps,
        !cfg.no_mask,
        None,
        cfg.eval_every,
        views,
        val_dir,
        device,
    )
    .with_mask_rays(cfg.mask_rays)?;
    task.eikonal_points = cfg.eikonal_points;
    Ok(task)
}

/// The pretraining phase of `cfg` (steps and learning rate resolved): the decaying learning
/// rate and the weights of the colour, mask and eikonal terms.
pub fn pretrain_phase(cfg: &IdrRunConfig) -> Phase<IdrObjective> {
    let phase = Phase::new("pretrain", IdrObjective::Pretrain, cfg.steps, cfg.lr)
        .schedule(LrSchedule {
            base: cfg.lr,
            decay: cfg.lr_decay,
            decay_steps: cfg.steps as f64,
        })
        .weight("rgb", 1.0)
        .weight("mse_mask", 0.0)
        .weight("eikonal", cfg.eikonal_weight);
    if cfg.no_mask {
        phase
    } else {
        phase.weight("mask", cfg.mask_weight)
    }
}

fn final_pictures(model: &IdrModel, task: &IdrTask, out: &Path, device: &Device) -> Result<()> {
    let views: Vec<usize> = if task.eval_views.is_empty() {
        task.scene
            .split(Split::Train)
            .iter()
            .copied()
            .take(2)
            .collect()
    } else {
        task.eval_views.iter().copied().take(6).collect()
    };
    let code = task
        .style
        .as_ref()
        .map(|s| s.codes.clone().slice([0..1]).inner().to_device(device));
    let evals = evaluate_views(
        &model.valid().to_device(device),
        &task.scene,
        &views,
        code,
        task.masked,
        &task.trace,
        device,
    )?;
    save_pictures(&evals, &out.join("val").join("final.png"))
}

/// A run folder loaded back.
pub struct IdrRun {
    /// The run folder.
    pub dir: PathBuf,
    /// Its configuration.
    pub config: IdrRunConfig,
    /// The pretrained run's configuration, for a stylized run.
    pub base: Option<IdrRunConfig>,
    /// The scene at the run's resolution, with the run's held-out views.
    pub scene: Scene,
    /// The model of the newest checkpoint.
    pub model: IdrModel,
}

impl IdrRun {
    /// Loads `dir` (written by `train idr`).
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let config_path = dir.join("config.json");
        if !config_path.is_file() {
            bail!(
                "{} is not an IDR run folder (no config.json)",
                dir.display()
            );
        }
        let config = IdrRunConfig::from_file(&config_path)
            .with_context(|| format!("{} is not an IDR run", dir.display()))?;
        let base = match config.kind()? {
            IdrKind::Pretrain => None,
            IdrKind::Stylize => {
                let from = config.from.clone().expect("kind checked");
                Some(
                    IdrRunConfig::from_file(&from.join("config.json"))
                        .with_context(|| format!("the base run of {}", dir.display()))?,
                )
            }
        };
        let scene_cfg = base.as_ref().unwrap_or(&config);
        let scene_path = scene_cfg
            .scene
            .clone()
            .context("the base run has no scene")?;
        let (scene, _) = load_scene(
            &scene_path,
            scene_cfg.downscale,
            scene_cfg.holdout,
            scene_cfg.no_mask,
        )?;
        let store = CheckpointStore::new(dir.join("checkpoints"), 2);
        let latest = store
            .latest_dir()?
            .with_context(|| format!("{}: no checkpoint in the run folder", dir.display()))?;
        let ckpt = CheckpointStore::load_dir(&latest)?;
        let mut model = IdrModel::new(&scene_cfg.arch(), device);
        if base.is_some() {
            model = model.with_stylizer(
                config.styles.len(),
                config.sim_width,
                config.position_freqs,
                device,
            );
        }
        let model = load_module_bytes(model, ckpt.model, &latest.join("model.bpk"))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            config,
            base,
            scene,
            model,
        })
    }

    /// Whether masks were used.
    pub fn masked(&self) -> bool {
        !self.base.as_ref().unwrap_or(&self.config).no_mask
    }

    /// A style code `[1, n]` from mix weights, or `None` for an unstylized run.
    pub fn code(&self, mix: Option<&[f32]>, device: &Device) -> Result<Option<Tensor<2>>> {
        crate::style_mix::code(self.model.n_styles(), mix, &self.dir, device)
    }
}

/// Learning-rate multiplier of the AM's blend weight γ. The SIM's features reach the colour
/// only as far as γ leaves 1, and Adam moves γ by about one learning rate per step: at the
/// others' rate (1e-3) the style loss on scan37 stayed flat for 160 of 200 steps, until γ had
/// moved.
pub const BLEND_LR_MULT: f64 = 10.0;

/// Stylizes the pretrained run `cfg.from` into `opts.out_dir`.
pub fn stylize(
    cfg: &IdrRunConfig,
    vgg: Vgg,
    device: &Device,
    opts: TrainOptions,
) -> Result<TrainOutcome<IdrModel>> {
    cfg.kind()?;
    let from = cfg.from.clone().context("stylizing needs --from RUN")?;
    let base = IdrRun::load(&from, device)?;
    if base.base.is_some() {
        bail!(
            "{} is already a stylized run; stylize its pretrained run instead",
            from.display()
        );
    }
    if cfg.sdf != base.config.sdf {
        bail!(
            "--sdf {} does not match the pretrained run {} (--sdf {})",
            cfg.sdf,
            from.display(),
            base.config.sdf
        );
    }
    let styles: Vec<RgbImage> = cfg
        .styles
        .iter()
        .map(|p| RgbImage::load(p))
        .collect::<Result<_>>()?;
    let mut cfg = cfg.clone();
    cfg.downscale = base.config.downscale;
    cfg.holdout = base.config.holdout;
    cfg.no_mask = base.config.no_mask;
    cfg.init_radius = base.config.init_radius;
    cfg.steps = cfg.steps_for(IdrKind::Stylize);
    cfg.lr = cfg.lr_for(IdrKind::Stylize);
    let out = opts.out_dir.clone();
    crate::config::write_run_config(&cfg, &out, opts.resume)?;
    let ad = device.clone().autodiff();
    let n = styles.len();
    let model = ins_core::train::seeding::seeded(&ad, cfg.seed, || {
        base.model
            .clone()
            .to_device(&ad)
            .with_stylizer(n, cfg.sim_width, cfg.position_freqs, &ad)
    });
    let vgg = vgg.to_device(&ad);
    let (w, h) = base.scene.resolution();
    let stride = if cfg.stride > 0 {
        cfg.stride as u32
    } else {
        ((0.5 * w.min(h) as f32 / cfg.patch.max(1) as f32).round() as u32).max(1)
    };
    let patch = PatchSpec::new(cfg.patch as u32, stride).fitted(w, h)?;
    let weights = LossWeights::or_defaults(vgg.preprocess, cfg.content_weight, cfg.style_weight);
    let targets = StyleTarget::stacked_from_images(&vgg, &styles, cfg.style_size, &ad);
    let style = SurfaceStylization {
        vgg,
        targets,
        codes: one_hot_codes(n, &ad),
        patch,
    };
    let views = base.scene.split(Split::Val).to_vec();
    let mut task = IdrTask::new(
        base.scene,
        cfg.rays,
        cfg.steps,
        !cfg.no_mask,
        Some(style),
        cfg.eval_every,
        views,
        out.join("val"),
        &ad,
    );
    let mut phase = Phase::new("stylize", IdrObjective::Stylize, cfg.steps, cfg.lr)
        .lr_mult("blend", BLEND_LR_MULT)
        .weight("style", weights.style)
        .weight("content", weights.content);
    phase = if cfg.sdf_lr_ratio > 0.0 {
        phase.lr_mult("sdf", cfg.sdf_lr_ratio)
    } else {
        phase.freeze("sdf")
    };
    let outcome = Trainer::new(vec![phase], opts).run(&mut task, model)?;
    if outcome.finished {
        final_pictures(&outcome.model, &task, &out, device)?;
    }
    Ok(outcome)
}
