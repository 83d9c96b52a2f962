//! NeRF runs end to end: pretraining a field on a scene, stylizing a pretrained run, and
//! loading a run folder back for rendering and evaluation.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::data::{LoadOptions, Scene, Split, detect_format};
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, StyleTarget};
use ins_core::modules::field::CimKind;
use ins_core::render::geometry::Vec3;
use ins_core::render::occupancy::OccupancyGrid;
use ins_core::render::patches::PatchSpec;
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes};
use ins_core::train::{LrSchedule, Phase, TrainOptions, TrainOutcome, Trainer};
use vgg_import::Vgg;

use super::config::{NerfRunConfig, RunKind, auto_downscale};
use super::eval::{evaluate_views, save_eval_picture};
use super::model::NerfModel;
use super::render::{Sampling, scene_aabb};
use super::task::{EvalSchedule, NerfObjective, NerfTask, Sampler, Stylization};
use crate::image_task::one_hot_codes;

/// A scene loaded at a run's resolution.
pub fn load_scene(path: &Path, downscale: u32) -> Result<(Scene, u32)> {
    detect_format(path)?;
    let factor = if downscale == 0 {
        // Peek at the full-size resolution through a cheap load of one split.
        let probe = Scene::load(path, &LoadOptions::default())?;
        let (w, h) = probe.resolution();
        auto_downscale(w, h, 512)
    } else {
        downscale
    };
    let scene = Scene::load(
        path,
        &LoadOptions {
            downscale: factor,
            ..Default::default()
        },
    )?;
    if scene.split(Split::Train).is_empty() {
        bail!("{}: the scene has no training views", path.display());
    }
    Ok((scene, factor))
}

/// Held-out views to evaluate: the val split, else the test split (LLFF holds every 8th view
/// out as both).
pub fn heldout_views(scene: &Scene) -> Vec<usize> {
    let val = scene.split(Split::Val);
    if !val.is_empty() {
        val.to_vec()
    } else {
        scene.split(Split::Test).to_vec()
    }
}

/// `n` views spread evenly over `views`.
fn spread(views: &[usize], n: usize) -> Vec<usize> {
    if views.len() <= n {
        return views.to_vec();
    }
    (0..n).map(|i| views[i * views.len() / n]).collect()
}

/// A fresh occupancy grid over a model's box.
pub fn fresh_grid(aabb: [f32; 6], resolution: u32) -> OccupancyGrid {
    let (min, max) = (
        Vec3::new(aabb[0], aabb[1], aabb[2]),
        Vec3::new(aabb[3], aabb[4], aabb[5]),
    );
    OccupancyGrid::new(
        resolution,
        min,
        max,
        OccupancyGrid::default_step(resolution, min, max),
    )
}

/// The sampler a run uses.
fn sampler(cfg: &NerfRunConfig, refresh: bool) -> Sampler {
    match cfg.cim {
        CimKind::Grid => Sampler::Marching {
            target_samples: cfg.target_samples,
            max_per_ray: cfg.max_samples_per_ray,
            refresh_every: if refresh { cfg.occupancy_every } else { 0 },
        },
        CimKind::Mlp => Sampler::CoarseFine {
            rays: cfg.rays,
            coarse: cfg.coarse_samples,
            fine: cfg.fine_samples,
        },
    }
}

/// The sampling used for rendering with a loaded run.
pub fn render_sampling<'a>(cfg: &NerfRunConfig, grid: Option<&'a OccupancyGrid>) -> Sampling<'a> {
    match (cfg.cim, grid) {
        (CimKind::Grid, Some(grid)) => Sampling::Occupancy {
            grid,
            max_per_ray: cfg.max_samples_per_ray.max(1024),
        },
        _ => Sampling::CoarseFine {
            coarse: cfg.coarse_samples,
            fine: cfg.fine_samples,
        },
    }
}

fn options_eval(cfg: &NerfRunConfig, scene: &Scene, out: &Path) -> EvalSchedule {
    EvalSchedule {
        every: cfg.eval_every,
        views: spread(&heldout_views(scene), cfg.eval_views),
        dir: out.join("val"),
    }
}

/// Pretrains a NeRF on `cfg.scene` into `opts.out_dir`.
pub fn pretrain(
    cfg: &NerfRunConfig,
    device: &Device,
    opts: TrainOptions,
) -> Result<TrainOutcome<NerfModel>> {
    let scene_path = cfg.scene.clone().context("pretraining needs --scene DIR")?;
    let (scene, factor) = load_scene(&scene_path, cfg.downscale)?;
    let mut cfg = cfg.clone();
    cfg.downscale = factor;
    cfg.steps = cfg.pretrain_steps_for(scene.format);
    cfg.lr = cfg.lr_for(RunKind::Pretrain);
    let out = opts.out_dir.clone();
    crate::config::write_run_config(&cfg, &out, opts.resume)?;
    let ad = device.clone().autodiff();
    let aabb = scene_aabb(&scene);
    let model =
        ins_core::train::seeding::seeded(&ad, cfg.seed, || NerfModel::new(&cfg.arch(), aabb, &ad));
    let grid = (cfg.cim == CimKind::Grid).then(|| fresh_grid(aabb, cfg.occupancy_resolution));
    let eval = options_eval(&cfg, &scene, &out);
    let mut task = NerfTask::new(scene, sampler(&cfg, true), grid, None, eval, &ad);
    let mut phase = Phase::new("pretrain", NerfObjective::Pretrain, cfg.steps, cfg.lr)
        .schedule(LrSchedule {
            base: cfg.lr,
            decay: 0.1,
            decay_steps: cfg.steps as f64,
        })
        .weight("mse", 1.0);
    if cfg.cim == CimKind::Mlp {
        phase = phase.weight("mse_coarse", 1.0);
    }
    let outcome = Trainer::new(vec![phase], opts).run(&mut task, model)?;
    if outcome.finished {
        final_report(&outcome.model, &task, &cfg, &out, device)?;
    }
    Ok(outcome)
}

/// Renders every held-out view at the end of a run: `val/final.png` and the mean scores.
fn final_report(
    model: &NerfModel,
    task: &NerfTask,
    cfg: &NerfRunConfig,
    out: &Path,
    device: &Device,
) -> Result<()> {
    let views = heldout_views(&task.scene);
    if views.is_empty() {
        return Ok(());
    }
    let shown = spread(&views, 8);
    let code = task
        .style
        .as_ref()
        .map(|s| s.codes.clone().slice([0..1]).inner().to_device(device));
    let evals = evaluate_views(
        &model.valid().to_device(device),
        &task.scene,
        &shown,
        render_sampling(cfg, task.grid.as_ref()),
        code,
        task.background,
        device,
    )?;
    let pictures: Vec<RgbImage> = evals.iter().map(|e| e.picture(&task.scene)).collect();
    save_eval_picture(&pictures, &out.join("val").join("final.png"))?;
    Ok(())
}

/// A run folder loaded back: its configuration, scene, model and occupancy grid.
pub struct NerfRun {
    /// The run folder.
    pub dir: PathBuf,
    /// Its configuration (for a stylized run, the scene settings of its base run).
    pub config: NerfRunConfig,
    /// The base (pretrained) run's configuration, for a stylized run.
    pub base: Option<NerfRunConfig>,
    /// The scene at the run's resolution.
    pub scene: Scene,
    /// The model of the newest checkpoint.
    pub model: NerfModel,
    /// The occupancy grid of the newest checkpoint (grid variant).
    pub grid: Option<OccupancyGrid>,
}

impl NerfRun {
    /// Loads `dir` (a folder written by `train nerf`) on `device`.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let config_path = dir.join("config.json");
        if !config_path.is_file() {
            bail!(
                "{} is not a NeRF run folder (no config.json)",
                dir.display()
            );
        }
        let config = NerfRunConfig::from_file(&config_path)
            .with_context(|| format!("{} is not a NeRF run", dir.display()))?;
        let (scene_cfg, base) = match config.kind()? {
            RunKind::Pretrain => (config.clone(), None),
            RunKind::Stylize => {
                let from = config.from.clone().expect("kind checked");
                let base = NerfRunConfig::from_file(&from.join("config.json"))
                    .with_context(|| format!("the base run of {}", dir.display()))?;
                (base.clone(), Some(base))
            }
        };
        let scene_path = scene_cfg
            .scene
            .clone()
            .context("the base run has no scene")?;
        let (scene, _) = load_scene(&scene_path, scene_cfg.downscale)?;
        let store = CheckpointStore::new(dir.join("checkpoints"), 2);
        let latest = store
            .latest_dir()?
            .with_context(|| format!("{}: no checkpoint in the run folder", dir.display()))?;
        let ckpt = CheckpointStore::load_dir(&latest)?;
        let mut model = NerfModel::new(&scene_cfg.arch(), scene_aabb(&scene), device);
        if base.is_some() {
            model = model.with_stylizer(
                config.styles.len(),
                config.sim_width_for(),
                config.position_freqs,
                device,
            );
        }
        let model = load_module_bytes(model, ckpt.model, &latest.join("model.bpk"))?;
        let grid = match ckpt.task {
            Some(bytes) => {
                super::state_io::decode(&bytes)
                    .with_context(|| format!("{}", latest.join("task.bin").display()))?
                    .1
            }
            None => None,
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            config,
            base,
            scene,
            model,
            grid,
        })
    }

    /// The configuration that defines the scene and the content module.
    pub fn scene_config(&self) -> &NerfRunConfig {
        self.base.as_ref().unwrap_or(&self.config)
    }

    /// The sampling for renders.
    pub fn sampling(&self) -> Sampling<'_> {
        render_sampling(self.scene_config(), self.grid.as_ref())
    }

    /// Background colour of the scene.
    pub fn background(&self) -> [f32; 3] {
        if self.scene.white_background {
            [1.0; 3]
        } else {
            [0.0; 3]
        }
    }

    /// A style code `[1, n]` from mix weights (normalised), or `None` for an unstylized run.
    pub fn code(&self, mix: Option<&[f32]>, device: &Device) -> Result<Option<Tensor<2>>> {
        crate::style_mix::code(self.model.n_styles(), mix, &self.dir, device)
    }
}

/// The stride that makes a K-ray patch span about 60 % of the image's shorter side.
fn patch_stride(cfg: &NerfRunConfig, scene: &Scene) -> u32 {
    if cfg.stride > 0 {
        return cfg.stride as u32;
    }
    let (w, h) = scene.resolution();
    ((0.6 * w.min(h) as f32 / cfg.patch.max(1) as f32).round() as u32).max(1)
}

/// Stylizes the pretrained run `cfg.from` with `cfg.styles` into `opts.out_dir`.
pub fn stylize(
    cfg: &NerfRunConfig,
    vgg: Vgg,
    device: &Device,
    opts: TrainOptions,
) -> Result<TrainOutcome<NerfModel>> {
    cfg.kind()?;
    let from = cfg.from.clone().context("stylizing needs --from RUN")?;
    let base = NerfRun::load(&from, device)?;
    if base.base.is_some() {
        bail!(
            "{} is already a stylized run; stylize its pretrained run ({}) instead",
            from.display(),
            base.config
                .from
                .as_ref()
                .map_or("?".into(), |p| p.display().to_string())
        );
    }
    if cfg.cim != base.config.cim {
        bail!(
            "--cim {} does not match the pretrained run {} (--cim {})",
            cfg.cim,
            from.display(),
            base.config.cim
        );
    }
    let styles: Vec<RgbImage> = cfg
        .styles
        .iter()
        .map(|p| RgbImage::load(p))
        .collect::<Result<_>>()?;
    let mut cfg = cfg.clone();
    // The scene settings are the pretrained run's.
    cfg.downscale = base.config.downscale;
    cfg.log2_table = base.config.log2_table;
    cfg.max_resolution = base.config.max_resolution;
    cfg.occupancy_resolution = base.config.occupancy_resolution;
    cfg.steps = cfg.steps_for(RunKind::Stylize);
    cfg.lr = cfg.lr_for(RunKind::Stylize);
    let out = opts.out_dir.clone();
    crate::config::write_run_config(&cfg, &out, opts.resume)?;

    let ad = device.clone().autodiff();
    let teacher = base.model.field.geometry.clone().to_device(&ad).no_grad();
    let n = styles.len();
    let model = ins_core::train::seeding::seeded(&ad, cfg.seed, || {
        base.model.clone().to_device(&ad).with_stylizer(
            n,
            cfg.sim_width_for(),
            cfg.position_freqs,
            &ad,
        )
    });
    let vgg = vgg.to_device(&ad);
    let (w, h) = base.scene.resolution();
    let patch = PatchSpec::new(cfg.patch as u32, patch_stride(&cfg, &base.scene)).fitted(w, h)?;
    let weights = LossWeights::or_defaults(vgg.preprocess, cfg.content_weight, cfg.style_weight);
    let targets = StyleTarget::stacked_from_images(&vgg, &styles, cfg.style_size, &ad);
    let style = Stylization {
        vgg,
        targets,
        codes: one_hot_codes(n, &ad),
        teacher,
        patch,
    };
    let eval = options_eval(&cfg, &base.scene, &out);
    let mut task = NerfTask::new(
        base.scene,
        sampler(&cfg, false),
        base.grid,
        Some(style),
        eval,
        &ad,
    );
    let mut phase = Phase::new("stylize", NerfObjective::Stylize, cfg.steps, cfg.lr)
        .weight("style", weights.style)
        .weight("content", weights.content)
        .weight("geometry", cfg.geometry_weight);
    if cfg.cim == CimKind::Mlp {
        phase = phase.freeze("coarse");
    }
    if !cfg.stylize_density {
        phase = phase.freeze("geometry").freeze("am_density");
    }
    let outcome = Trainer::new(vec![phase], opts).run(&mut task, model)?;
    if outcome.finished {
        final_report(&outcome.model, &task, &cfg, &out, device)?;
    }
    Ok(outcome)
}
