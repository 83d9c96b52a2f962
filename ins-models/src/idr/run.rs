//! IDR on the shared run layer: what an IDR run loads, builds, trains and reports. Pretraining
//! reconstructs a surface from masked photos; stylizing trains SIM + AM inside the rendering
//! network with the perceptual loss on patches inside the mask, the surface frozen by default.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::loss::{LossWeights, PerceptualLoss, StyleLoss};
use ins_core::modules::style_position::TEXTURE_LR_MULT;
use ins_core::train::{LrSchedule, Phase, RunFolder};
use ins_scene::data::{Scene, SceneFormat, Split, detect_format};
use ins_scene::patches::PatchSpec;

use super::config::IdrRunConfig;
use super::eval::{evaluate_views, mean_scores, save_pictures};
use super::model::{IdrModel, SdfRenderer};
use super::task::{IdrObjective, IdrTask, SurfaceStylization};
use crate::run::scene_frame::{check_scene_frame, write_scene_frame};
use crate::run::{FinalScores, Run, RunKind, Start, Variant};

/// IDR + INS.
pub struct Idr;

/// An IDR run folder loaded back.
pub type IdrRun = Run<Idr>;

/// Share of the image's shorter side a stylization patch spans (see `PatchSpec::spanning`).
pub const PATCH_SHARE: f32 = 0.5;

/// Learning-rate multiplier of the AM's blend weight γ. The SIM's features reach the colour
/// only as far as γ leaves 1, and Adam moves γ by about one learning rate per step: at the
/// others' rate (1e-3) the style loss on scan37 stayed flat for 160 of 200 steps, until γ had
/// moved.
pub const BLEND_LR_MULT: f64 = 10.0;

/// Learning-rate multiplier of the volume renderer's sharpness while pretraining. NeuS moves
/// it at the others' rate over 300k steps; in a few thousand, at 5e-3, s had only climbed from
/// 20 to 66 by step 1000 on scan37, leaving a blurred band outside the silhouette (IoU 0.89).
pub const SHARPNESS_LR_MULT: f64 = 4.0;

/// Samples near the surface per step where the smoothness term (`--curvature-weight`) looks:
/// each costs one more forward-mode gradient and its backward.
const CURVATURE_POINTS: usize = 2048;

/// Loads a scene for surface reconstruction, in the unit-sphere frame IDR works in: DTU ships
/// it; an object captured from around it (COLMAP, transforms.json, NeRF-synthetic) is placed
/// there from its masks' visual hull (`ins_scene::data::unit_sphere`), or with `no_mask` from
/// its sparse points (else its cameras), said in a note. Masks must exist unless `no_mask`,
/// and every `holdout`-th view goes to val (0: the format's own hold-out).
pub fn load_scene(
    path: &Path,
    downscale: u32,
    images: Option<&Path>,
    holdout: usize,
    no_mask: bool,
) -> Result<(Scene, u32)> {
    let format = detect_format(path)?;
    if format == SceneFormat::Llff {
        bail!(
            "{}: IDR reconstructs the surface of an object photographed from around it; this is a forward-facing {format} scene — train a NeRF on it instead (`ins-cli train nerf`)",
            path.display()
        );
    }
    let (scene, _, factor) = crate::run::scene::load_scene(path, downscale, images)?;
    let masked = scene.views.iter().all(|v| v.mask.is_some());
    if !no_mask && !masked {
        bail!(
            "{}: IDR needs an object mask per view ({}); pass --no-mask to train without them (colour on the whole image; with --renderer volume a field beyond the unit sphere takes the background)",
            path.display(),
            match format {
                SceneFormat::Dtu => "a mask/ folder",
                SceneFormat::Colmap =>
                    "a masks/ folder beside images/, NAME.png for each photo NAME",
                SceneFormat::Transforms => "a mask_path in each frame of transforms.json",
                _ => "an alpha channel in each image",
            }
        );
    }
    let mut scene = if format == SceneFormat::Dtu {
        scene
    } else {
        let known = scene.notes.len();
        let scene = ins_scene::data::unit_sphere::into_unit_sphere(scene, !no_mask)?.0;
        for note in &scene.notes[known..] {
            eprintln!("note: {note}");
        }
        scene
    };
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

impl Variant for Idr {
    const NAME: &'static str = "IDR";
    const KEY: &'static str = "idr";
    type Config = IdrRunConfig;
    type Data = Scene;
    type Model = IdrModel;
    type Objective = IdrObjective;
    type Task = IdrTask;
    type Extra = ();

    fn kind(cfg: &IdrRunConfig) -> Result<RunKind> {
        let kind = cfg.kind()?;
        if kind == RunKind::Pretrain {
            validate_pretraining(cfg)?;
        }
        Ok(kind)
    }

    fn load_data(cfg: &mut IdrRunConfig) -> Result<Scene> {
        let path = cfg
            .source
            .scene
            .clone()
            .context("pretraining needs --scene DIR")?;
        let (scene, factor) = load_scene(
            &path,
            cfg.source.downscale,
            cfg.source.images.as_deref(),
            cfg.holdout,
            cfg.no_mask,
        )?;
        cfg.source.downscale = factor;
        Ok(scene)
    }

    fn check_data(data: &Scene, field_run: &RunFolder) -> Result<()> {
        check_scene_frame(data, &field_run.scene_frame())
    }

    fn palette(data: &Scene, max: usize) -> Vec<[f32; 3]> {
        data.object_colors(Split::Train, max)
    }

    fn resolve(cfg: &mut IdrRunConfig, kind: RunKind, _data: &Scene) {
        cfg.schedule.steps = cfg.steps_for(kind);
        cfg.schedule.lr = cfg.lr_for(kind);
        cfg.style.resolve(64, 256, StyleLoss::Nnfm);
        cfg.stylizer.sim_width = cfg.sim_width_for();
        cfg.rays = cfg.rays_for();
        cfg.mask_weight = cfg.mask_weight_for();
        cfg.mask_rays = Some(cfg.mask_rays_for());
        cfg.eikonal_points = Some(cfg.eikonal_points_for());
        cfg.eval_every = Some(cfg.eval_every_for());
        cfg.curvature_weight = Some(cfg.curvature_weight_for());
        cfg.color_grid = Some(cfg.color_grid_for());
    }

    fn inherit(cfg: &mut IdrRunConfig, base: &IdrRunConfig, from: &Path) -> Result<()> {
        if cfg.sdf != base.sdf {
            bail!(
                "--sdf {} does not match the pretrained run {} (--sdf {})",
                cfg.sdf,
                from.display(),
                base.sdf
            );
        }
        cfg.source.downscale = base.source.downscale;
        cfg.holdout = base.holdout;
        cfg.no_mask = base.no_mask;
        cfg.init_radius = base.init_radius;
        // The model's parts follow how it was pretrained (a volume run has a sharpness).
        cfg.renderer = base.renderer;
        cfg.color_grid = Some(base.color_grid_for());
        cfg.stylize_color_grid = base.color_grid_for() > 0;
        cfg.grid_table = base.grid_table;
        // The frozen surface is rendered with the samples that resolved it.
        cfg.samples = base.samples;
        cfg.kept_samples = base.kept_samples;
        cfg.fine_samples = base.fine_samples;
        cfg.upsample_rounds = base.upsample_rounds;
        Ok(())
    }

    fn new_model(cfg: &IdrRunConfig, _data: &Scene, device: &Device) -> IdrModel {
        IdrModel::new(&cfg.arch(), device)
    }

    fn add_stylizer(
        model: IdrModel,
        cfg: &IdrRunConfig,
        n_styles: usize,
        device: &Device,
    ) -> IdrModel {
        model.with_stylizer(
            n_styles,
            cfg.sim_width_for(),
            &cfg.stylizer.position(),
            cfg.stylize_color_grid,
            device,
        )
    }

    fn task(
        cfg: &IdrRunConfig,
        start: Start<Idr>,
        style: Option<PerceptualLoss>,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<IdrTask> {
        match start {
            Start::Fresh(scene) => {
                write_scene_frame(&scene, &folder.scene_frame())?;
                let views = scene.split(Split::Val).to_vec();
                pretrain_task(cfg, scene, views, folder.val_dir(), device)
            }
            Start::From(base) => {
                let perceptual = style.context("stylizing needs the paintings' loss")?;
                let scene = base.data;
                let (w, h) = scene.smallest_resolution();
                let patch = PatchSpec::spanning(
                    cfg.style.patch as u32,
                    cfg.style.stride as u32,
                    PATCH_SHARE,
                    w,
                    h,
                )?;
                let style = SurfaceStylization { perceptual, patch };
                let views = scene.split(Split::Val).to_vec();
                let mut task = IdrTask::new(
                    scene,
                    cfg.rays_for(),
                    cfg.schedule.steps,
                    !cfg.no_mask,
                    Some(style),
                    cfg.eval_every_for(),
                    views,
                    folder.val_dir(),
                    device,
                );
                task.sampling = cfg.volume_sampling();
                Ok(task)
            }
        }
    }

    fn phases(cfg: &IdrRunConfig, kind: RunKind, weights: LossWeights) -> Vec<Phase<IdrObjective>> {
        let phase = match kind {
            RunKind::Pretrain => pretrain_phase(cfg),
            RunKind::Stylize => {
                let (steps, lr) = (cfg.schedule.steps, cfg.schedule.lr);
                let mut phase = Phase::new("stylize", IdrObjective::Stylize, steps, lr)
                    .lr_mult("blend", BLEND_LR_MULT)
                    .weight("style", weights.style)
                    .weight("content", weights.content);
                if cfg.stylizer.sim_grid > 0 {
                    phase = phase.lr_mult("texture", TEXTURE_LR_MULT);
                }
                if cfg.renderer == SdfRenderer::Volume {
                    // The sharpness belongs to the surface: it stays as pretrained.
                    phase = phase.freeze("sharpness");
                }
                if cfg.arch().background {
                    // What lies beyond the sphere is the photos', not the painting's.
                    phase = phase.freeze("background");
                }
                if cfg.sdf_lr_ratio > 0.0 {
                    phase.lr_mult("sdf", cfg.sdf_lr_ratio)
                } else {
                    phase.freeze("sdf")
                }
            }
        };
        vec![phase]
    }

    /// Renders the held-out views and (pretraining) scores them as `eval idr` does;
    /// `val/final.png` shows up to six (two training views, unscored, for a run without any).
    fn final_report(
        model: &IdrModel,
        task: &IdrTask,
        _cfg: &IdrRunConfig,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<FinalScores> {
        let views: Vec<usize> = if task.eval_views.is_empty() {
            task.scene
                .split(Split::Train)
                .iter()
                .copied()
                .take(2)
                .collect()
        } else {
            task.eval_views.clone()
        };
        let code = task
            .style
            .as_ref()
            .map(|s| s.perceptual.first_code().to_device(device));
        let evals = evaluate_views(
            &model.valid().to_device(device),
            &task.scene,
            &views,
            code,
            &task.view_options(),
            device,
        )?;
        save_pictures(&evals[..evals.len().min(6)], &folder.final_picture())?;
        // A stylized render is not meant to match the photos.
        Ok(if task.eval_views.is_empty() || task.style.is_some() {
            FinalScores::new()
        } else {
            mean_scores(&evals)
        })
    }
}

/// Pretraining options out of range, refused before anything is loaded or written.
fn validate_pretraining(cfg: &IdrRunConfig) -> Result<()> {
    cfg.arch().validate().map_err(anyhow::Error::msg)?;
    let mask_rays = cfg.mask_rays_for();
    if !(0.0..=1.0).contains(&mask_rays) {
        bail!("--mask-rays {mask_rays}: the share of rays inside the masks is from 0 to 1");
    }
    let curvature = cfg.curvature_weight_for();
    if !(curvature >= 0.0 && curvature.is_finite()) {
        bail!("--curvature-weight {curvature}: a weight is 0 or more");
    }
    if curvature > 0.0 && cfg.renderer != SdfRenderer::Volume {
        bail!(
            "--curvature-weight {curvature}: the smoothness term is the volume renderer's (add --renderer volume)"
        );
    }
    if !(1..=8).contains(&cfg.upsample_rounds) {
        bail!(
            "--upsample-rounds {}: the fine samples are drawn in 1 to 8 rounds",
            cfg.upsample_rounds
        );
    }
    if !(cfg.lr_decay > 0.0 && cfg.lr_decay <= 1.0) {
        bail!(
            "--lr-decay {}: the final learning rate is a fraction of the first, above 0 and at most 1",
            cfg.lr_decay
        );
    }
    Ok(())
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
        cfg.rays_for(),
        cfg.schedule.steps,
        !cfg.no_mask,
        None,
        cfg.eval_every_for(),
        views,
        val_dir,
        device,
    )
    .with_mask_rays(cfg.mask_rays_for())?;
    task.eikonal_points = cfg.eikonal_points_for();
    task.renderer = cfg.renderer;
    task.sampling = cfg.volume_sampling();
    if cfg.renderer == SdfRenderer::Volume && cfg.curvature_weight_for() > 0.0 {
        task.curvature_points = CURVATURE_POINTS;
    }
    Ok(task)
}

/// The pretraining phase of `cfg` (steps and learning rate resolved): the decaying learning
/// rate and the weights of the colour, mask and eikonal terms.
pub fn pretrain_phase(cfg: &IdrRunConfig) -> Phase<IdrObjective> {
    let (steps, lr) = (cfg.schedule.steps, cfg.schedule.lr);
    let phase = Phase::new("pretrain", IdrObjective::Pretrain, steps, lr)
        .schedule(LrSchedule {
            base: lr,
            decay: cfg.lr_decay,
            decay_steps: steps as f64,
        })
        .weight("rgb", 1.0)
        .weight("mse_mask", 0.0)
        .weight("eikonal", cfg.eikonal_weight);
    let phase = if cfg.renderer == SdfRenderer::Volume {
        let phase = phase.lr_mult("sharpness", SHARPNESS_LR_MULT);
        if cfg.curvature_weight_for() > 0.0 {
            phase.weight("curvature", cfg.curvature_weight_for())
        } else {
            phase
        }
    } else {
        phase
    };
    if cfg.no_mask {
        phase
    } else {
        phase.weight("mask", cfg.mask_weight_for())
    }
}

impl Run<Idr> {
    /// The scene at the run's resolution, with the run's held-out views.
    pub fn scene(&self) -> &Scene {
        &self.data
    }

    /// Whether masks were used.
    pub fn masked(&self) -> bool {
        !self.scene_config().no_mask
    }
}
