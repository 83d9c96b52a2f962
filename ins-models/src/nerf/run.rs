//! NeRF on the shared run layer: what a NeRF run loads, builds, trains and reports. Pretraining
//! fits a field to a scene's photos; stylizing copies a pretrained run's field, freezes it as
//! the teacher of the geometry loss, and trains SIM + AM with the perceptual loss.

use std::path::Path;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, PerceptualLoss, StyleLoss};
use ins_core::modules::field::{CimKind, Geometry};
use ins_core::modules::style_position::TEXTURE_LR_MULT;
use ins_core::render::occupancy::OccupancyGrid;
use ins_core::train::{LrSchedule, Phase, RunFolder};
use ins_scene::data::{Scene, SceneFormat};
use ins_scene::geometry::Vec3;
use ins_scene::patches::PatchSpec;

use super::background::{fixed_background, learns_background};
use super::config::NerfRunConfig;
use super::eval::{evaluate_views, save_eval_picture};
use super::model::NerfModel;
use super::render::{Sampling, scene_aabb};
use super::state_io::NerfState;
use super::task::{EvalSchedule, NerfObjective, NerfTask, Sampler, Stylization};
use crate::run::scene::{heldout_views, load_scene, spread};
use crate::run::scene_frame::{check_scene_frame, write_scene_frame};
use crate::run::{FinalScores, Run, RunKind, Start, Variant};

/// NeRF + INS.
pub struct Nerf;

/// A NeRF run folder loaded back.
pub type NerfRun = Run<Nerf>;

/// A loaded NeRF scene: the posed photos at the run's resolution and their format.
pub struct NerfScene {
    /// The photos and cameras.
    pub scene: Scene,
    /// The folder's format (forward-facing LLFF scenes train longer).
    pub format: SceneFormat,
}

/// How much lower the fresh field of a capture that learns its background starts its raw
/// density (`exp(−4)`: about 0.02 per unit, so a ray crosses the box nearly unhindered and the
/// learned background is seen). At the usual start (about 1 per unit) every ray was opaque
/// within a few units of its camera from the first step, the background never showed, and a
/// plain backdrop stayed painted on that haze.
const CAPTURE_DENSITY_OFFSET: f32 = 4.0;

/// Share of the image's shorter side a stylization patch spans (see `PatchSpec::spanning`).
pub const PATCH_SHARE: f32 = 0.6;

impl Variant for Nerf {
    const NAME: &'static str = "NeRF";
    const KEY: &'static str = "nerf";
    type Config = NerfRunConfig;
    type Data = NerfScene;
    type Model = NerfModel;
    type Objective = NerfObjective;
    type Task = NerfTask;
    type Extra = NerfState;

    fn kind(cfg: &NerfRunConfig) -> Result<RunKind> {
        cfg.kind()
    }

    fn load_data(cfg: &mut NerfRunConfig) -> Result<NerfScene> {
        let path = cfg
            .source
            .scene
            .clone()
            .context("pretraining needs --scene DIR")?;
        let (scene, format, factor) =
            load_scene(&path, cfg.source.downscale, cfg.source.images.as_deref())?;
        cfg.source.downscale = factor;
        Ok(NerfScene { scene, format })
    }

    fn check_data(data: &NerfScene, field_run: &RunFolder) -> Result<()> {
        check_scene_frame(&data.scene, &field_run.scene_frame())
    }

    fn palette(data: &NerfScene, max: usize) -> Vec<[f32; 3]> {
        data.scene.object_colors(ins_scene::data::Split::Train, max)
    }

    fn resolve(cfg: &mut NerfRunConfig, kind: RunKind, data: &NerfScene) {
        cfg.schedule.steps = match kind {
            RunKind::Pretrain => cfg.pretrain_steps_for(data.scene.forward_facing),
            RunKind::Stylize => cfg.steps_for(kind),
        };
        cfg.schedule.lr = cfg.lr_for(kind);
        cfg.style.resolve(64, 256, StyleLoss::Nnfm);
    }

    fn inherit(cfg: &mut NerfRunConfig, base: &NerfRunConfig, from: &Path) -> Result<()> {
        if cfg.cim != base.cim {
            bail!(
                "--cim {} does not match the pretrained run {} (--cim {})",
                cfg.cim,
                from.display(),
                base.cim
            );
        }
        cfg.source.downscale = base.source.downscale;
        cfg.log2_table = base.log2_table;
        cfg.max_resolution = base.max_resolution;
        cfg.occupancy_resolution = base.occupancy_resolution;
        Ok(())
    }

    fn new_model(cfg: &NerfRunConfig, data: &NerfScene, device: &Device) -> NerfModel {
        let mut model = NerfModel::new(&cfg.arch(), scene_aabb(&data.scene), device);
        if learns_background(&data.scene) {
            if let Geometry::Grid(g) = model.field.geometry {
                model.field.geometry =
                    Geometry::Grid(g.with_density_offset(CAPTURE_DENSITY_OFFSET));
            }
        }
        model
    }

    fn add_stylizer(
        model: NerfModel,
        cfg: &NerfRunConfig,
        n_styles: usize,
        device: &Device,
    ) -> NerfModel {
        model.with_stylizer(
            n_styles,
            cfg.sim_width_for(),
            &cfg.stylizer.position(),
            device,
        )
    }

    fn task(
        cfg: &NerfRunConfig,
        start: Start<Nerf>,
        style: Option<PerceptualLoss>,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<NerfTask> {
        match start {
            Start::Fresh(data) => {
                if cfg.cim == CimKind::Mlp && data.scene.contraction.is_some() {
                    bail!(
                        "{}: an unbounded capture (background past the cameras) renders with \
                         the grid content module only; drop --cim mlp",
                        data.scene.root.display()
                    );
                }
                let grid = (cfg.cim == CimKind::Grid)
                    .then(|| fresh_grid(&data.scene, cfg.occupancy_resolution));
                write_scene_frame(&data.scene, &folder.scene_frame())?;
                let eval = eval_schedule(cfg, &data.scene, folder);
                let audit = (cfg.drop_misposed && super::view_audit::audits_views(&data.scene))
                    .then(|| {
                        let steps = cfg.pretrain_steps_for(data.scene.forward_facing);
                        (super::view_audit::AUDIT_AT * steps as f64).round() as usize
                    });
                let task = NerfTask::new(data.scene, sampler(cfg, true), grid, None, eval, device);
                Ok(match audit {
                    Some(at) => task.with_view_audit(at),
                    None => task,
                })
            }
            Start::From(mut base) => {
                let perceptual = style.context("stylizing needs the paintings' loss")?;
                let scene = base.data.scene;
                let (w, h) = scene.smallest_resolution();
                let patch = PatchSpec::spanning(
                    cfg.style.patch as u32,
                    cfg.style.stride as u32,
                    PATCH_SHARE,
                    w,
                    h,
                )?;
                let style = Stylization {
                    perceptual,
                    // With the density kept the student's density is the teacher's: no term.
                    teacher: cfg
                        .stylize_density
                        .then(|| base.model.field.geometry.to_device(device).no_grad()),
                    patch,
                    backprop_chunk: cfg.backprop_chunk,
                };
                let eval = eval_schedule(cfg, &scene, folder);
                Ok(NerfTask::new(
                    scene,
                    sampler(cfg, false),
                    base.extra.grid.take(),
                    Some(style),
                    eval,
                    device,
                )
                .continuing(&base.extra))
            }
        }
    }

    fn phases(
        cfg: &NerfRunConfig,
        kind: RunKind,
        weights: LossWeights,
    ) -> Vec<Phase<NerfObjective>> {
        let (steps, lr) = (cfg.schedule.steps, cfg.schedule.lr);
        let phase = match kind {
            RunKind::Pretrain => {
                let phase = Phase::new("pretrain", NerfObjective::Pretrain, steps, lr)
                    .schedule(LrSchedule {
                        base: lr,
                        decay: 0.1,
                        decay_steps: steps as f64,
                    })
                    .weight("mse", 1.0);
                if cfg.cim == CimKind::Mlp {
                    phase.weight("mse_coarse", 1.0)
                } else {
                    phase
                }
            }
            RunKind::Stylize => {
                let mut phase = Phase::new("stylize", NerfObjective::Stylize, steps, lr)
                    .weight("style", weights.style)
                    .weight("content", weights.content)
                    .weight("geometry", cfg.geometry_weight);
                if cfg.cim == CimKind::Mlp {
                    phase = phase.freeze("coarse");
                }
                if !cfg.stylize_density {
                    phase = phase.freeze("geometry").freeze("am_density");
                }
                if cfg.stylizer.sim_grid > 0 {
                    phase = phase.lr_mult("texture", TEXTURE_LR_MULT);
                }
                phase
            }
        };
        vec![phase]
    }

    /// Renders up to eight held-out views at the end of a run, spread over them:
    /// `val/final.png`, and (pretraining) their mean PSNR and SSIM.
    fn final_report(
        model: &NerfModel,
        task: &NerfTask,
        cfg: &NerfRunConfig,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<FinalScores> {
        let views = heldout_views(&task.scene);
        if views.is_empty() {
            return Ok(FinalScores::new());
        }
        let shown = spread(&views, 8);
        let code = task
            .style
            .as_ref()
            .map(|s| s.perceptual.first_code().to_device(device));
        let evals = evaluate_views(
            &model.valid().to_device(device),
            &task.scene,
            &shown,
            render_sampling(cfg, task.grid.as_ref()),
            code,
            task.background(),
            device,
        )?;
        let pictures: Vec<RgbImage> = evals.iter().map(|e| e.picture(&task.scene)).collect();
        save_eval_picture(&pictures, &folder.final_picture())?;
        if task.style.is_some() {
            // A stylized render is not meant to match the photos.
            return Ok(FinalScores::new());
        }
        let n = evals.len() as f64;
        Ok(FinalScores::from([
            ("views".into(), n),
            ("psnr".into(), evals.iter().map(|e| e.psnr).sum::<f64>() / n),
            ("ssim".into(), evals.iter().map(|e| e.ssim).sum::<f64>() / n),
        ]))
    }
}

/// A fresh occupancy grid over a scene's field box (contracted for unbounded scenes).
pub fn fresh_grid(scene: &Scene, resolution: u32) -> OccupancyGrid {
    if let Some(c) = scene.contraction {
        return OccupancyGrid::contracted(resolution, c);
    }
    let aabb = scene_aabb(scene);
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

/// The sampler a run trains with.
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
            until_opaque: None,
        },
        _ => Sampling::CoarseFine {
            coarse: cfg.coarse_samples,
            fine: cfg.fine_samples,
        },
    }
}

/// Held-out evaluation while training: `eval_views` views spread over the held-out ones.
fn eval_schedule(cfg: &NerfRunConfig, scene: &Scene, folder: &RunFolder) -> EvalSchedule {
    EvalSchedule {
        every: cfg.eval_every,
        views: spread(&heldout_views(scene), cfg.eval_views),
        dir: folder.val_dir(),
    }
}

impl Run<Nerf> {
    /// The scene at the run's resolution.
    pub fn scene(&self) -> &Scene {
        &self.data.scene
    }

    /// The occupancy grid of the newest checkpoint (grid variant).
    pub fn grid(&self) -> Option<&OccupancyGrid> {
        self.extra.grid.as_ref()
    }

    /// The sampling for renders.
    pub fn sampling(&self) -> Sampling<'_> {
        render_sampling(self.scene_config(), self.grid())
    }

    /// Background colour of the scene: white for alpha-composited photos, the learned one
    /// for an object capture in a box, else black.
    pub fn background(&self) -> [f32; 3] {
        let fixed = fixed_background(self.scene());
        match &self.extra.background {
            Some(b) => b.colour(fixed),
            None => fixed,
        }
    }
}
