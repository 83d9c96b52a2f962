//! The NeRF task the trainer runs: photometric pretraining on random rays, or stylization on
//! strided patches with VGG losses and the frozen-teacher geometry loss; the occupancy grid is
//! refreshed from the model, and held-out views are evaluated as training goes.

use std::path::PathBuf;

use anyhow::{Context, Result};
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{PerceptualLoss, mse, patch_images, photo_patch, psnr};
use ins_core::modules::field::Geometry;
use ins_core::render::occupancy::OccupancyGrid;
use ins_core::shape_buckets::nearest_bucket;
use ins_core::train::{LossTerms, StepContext, Task};
use ins_scene::data::{Scene, Split};
use ins_scene::patches::{PatchSampler, PatchSpec};
use ins_scene::rays::RaySampler;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::background::SceneBackground;
use super::deferred::PatchRender;
use super::early_stop::INVISIBLE_TRANSMITTANCE;
use super::eval::{evaluate_views, save_eval_picture};
use super::model::NerfModel;
use super::render::{RenderRays, Rendered, Sampling, render};
use super::state_io::NerfState;

/// What a phase of a NeRF run computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NerfObjective {
    /// Photometric MSE on random rays of the training views.
    Pretrain,
    /// Style, content and geometry losses on strided patches.
    Stylize,
}

/// How rays are sampled along, per variant.
#[derive(Debug, Clone, Copy)]
pub enum Sampler {
    /// Occupancy-grid marching with an adaptive ray count: about `target_samples` per step.
    Marching {
        /// Fine samples per step aimed at.
        target_samples: usize,
        /// Cap per ray.
        max_per_ray: usize,
        /// Steps between grid refreshes (0: the grid is fixed).
        refresh_every: usize,
    },
    /// NeRF's coarse-to-fine sampling with a fixed ray count.
    CoarseFine {
        /// Rays per step.
        rays: usize,
        /// Stratified samples.
        coarse: usize,
        /// Importance samples.
        fine: usize,
    },
}

/// What stylization needs.
pub struct Stylization {
    /// VGG, the paintings' targets and the style codes.
    pub perceptual: PerceptualLoss,
    /// The pretrained geometry, frozen: the teacher of the geometry loss. `None` when the
    /// density is kept (frozen), where the student's density is the teacher's and the term is
    /// 0 with no gradient: evaluating the teacher at every sample would cost a field pass.
    pub teacher: Option<Geometry>,
    /// Patch geometry.
    pub patch: PatchSpec,
    /// Patches of more rays than this are back-propagated in chunks of this many
    /// ([`deferred`](super::deferred)).
    pub backprop_chunk: usize,
}

/// The self-distilled geometry loss: mean |σ_student − σ_teacher| of the raw densities `[S, N]`
/// the student gave at `points [N, 3]` under each style, the frozen teacher evaluated at the
/// same points.
pub fn geometry_loss(teacher: &Geometry, points: Tensor<2>, raw: Tensor<2>) -> Tensor<1> {
    let (teacher_raw, _) = teacher.forward(points.detach());
    let [s, n] = raw.dims();
    (raw - teacher_raw.detach().reshape([1, n]).expand([s, n]))
        .abs()
        .mean()
}

/// Held-out evaluation during training.
pub struct EvalSchedule {
    /// Steps between evaluations (0: never during training).
    pub every: usize,
    /// Views rendered each time.
    pub views: Vec<usize>,
    /// Where pictures go.
    pub dir: PathBuf,
}

/// The task.
pub struct NerfTask {
    /// The scene.
    pub scene: Scene,
    /// How rays are sampled along.
    pub sampler: Sampler,
    /// The occupancy grid (grid variant).
    pub grid: Option<OccupancyGrid>,
    /// Running mean of fine samples per ray (sets the ray count).
    pub samples_per_ray: f32,
    /// Set for stylization runs.
    pub style: Option<Stylization>,
    /// Evaluation schedule.
    pub eval: EvalSchedule,
    /// Background colour: white for alpha-composited photos, black for datasets and contracted
    /// captures; an object capture in a box learns its own (see [`SceneBackground`]).
    background: SceneBackground,
    /// Pretraining step (in its phase) after which the training photos are audited
    /// ([`view_audit`](super::view_audit)); `None`: never.
    audit_at: Option<usize>,
    /// Training views the audit left out, worst first.
    dropped_views: Vec<usize>,
    device: Device,
    last_samples: usize,
    last_rays: usize,
}

/// Grid refreshes evaluate every cell during the first steps (while the field takes shape),
/// keeping only the latest densities (except in forward-facing scenes), then a quarter of the
/// cells (half uniformly, half among occupied ones) into a decaying running maximum, as
/// instant-ngp does.
const WARMUP_STEPS: usize = 256;
const REFRESH_SHARE: usize = 4;

impl NerfTask {
    /// A task on `scene` computing on `device` (an autodiff device).
    pub fn new(
        scene: Scene,
        sampler: Sampler,
        grid: Option<OccupancyGrid>,
        style: Option<Stylization>,
        eval: EvalSchedule,
        device: &Device,
    ) -> Self {
        let background = SceneBackground::for_scene(&scene, device);
        Self {
            scene,
            sampler,
            grid,
            samples_per_ray: 64.0,
            style,
            eval,
            background,
            audit_at: None,
            dropped_views: Vec::new(),
            device: device.clone(),
            last_samples: 0,
            last_rays: 0,
        }
    }

    /// Continues from a pretrained run's state: its learned background and the photos its
    /// audit left out (stylization keeps both).
    pub fn continuing(mut self, state: &NerfState) -> Self {
        self.adopt(state);
        self
    }

    /// Audits the training photos once `steps_in` steps of pretraining are done (a capture's;
    /// see [`view_audit`](super::view_audit)).
    pub fn with_view_audit(mut self, steps_in: usize) -> Self {
        self.audit_at = Some(steps_in.max(1));
        self
    }

    /// Takes over a state's learned background (its sums and the colour they give) and
    /// leaves out the photos it dropped.
    fn adopt(&mut self, state: &NerfState) {
        if let Some(b) = state.background {
            self.background.adopt(b, &self.device);
        }
        self.drop_views(&state.dropped_views);
    }

    fn drop_views(&mut self, views: &[usize]) {
        self.scene.train.retain(|v| !views.contains(v));
        for &v in views {
            if !self.dropped_views.contains(&v) {
                self.dropped_views.push(v);
            }
        }
    }

    /// Scores every training photo against the field and leaves out those posed wrongly,
    /// naming them. Returns how many were dropped.
    fn audit_views(&mut self, model: &NerfModel, seed: u64) -> Result<usize> {
        let background = self.background.read();
        let model = model.valid();
        let device = self.device.clone().inner();
        let fits = super::view_audit::fit_views(
            &model,
            &self.scene,
            &self.scene.train,
            self.sampling(),
            background,
            seed,
            &device,
        )?;
        let out = super::view_audit::outliers(&fits);
        if out.is_empty() {
            return Ok(0);
        }
        let median = super::view_audit::median_psnr(&fits);
        let names: Vec<String> = out
            .iter()
            .map(|f| {
                let name = super::view_audit::photo_name(&self.scene, f.view);
                format!("{name} ({:.1} dB)", f.psnr)
            })
            .collect();
        eprintln!(
            "{} of {} training photos fit far below the others (median {median:.1} dB): {}; \
             their poses are likely wrong, training goes on without them \
             (--drop-misposed false keeps them)",
            out.len(),
            fits.len(),
            names.join(", ")
        );
        let views: Vec<usize> = out.iter().map(|f| f.view).collect();
        self.drop_views(&views);
        Ok(views.len())
    }

    /// The background colour now (a learned one read from the device if it moved).
    pub fn background(&self) -> [f32; 3] {
        self.background.now()
    }

    /// The sampling for this step's render.
    fn sampling(&self) -> Sampling<'_> {
        match (self.sampler, &self.grid) {
            (Sampler::Marching { max_per_ray, .. }, Some(grid)) => Sampling::Occupancy {
                grid,
                max_per_ray,
                // Stylizing with the density kept (no teacher: the density is the pretrained
                // one), a ray's samples behind its surface show nothing.
                until_opaque: self
                    .style
                    .as_ref()
                    .is_some_and(|s| s.teacher.is_none())
                    .then_some(INVISIBLE_TRANSMITTANCE),
            },
            (Sampler::CoarseFine { coarse, fine, .. }, _) => Sampling::CoarseFine { coarse, fine },
            (Sampler::Marching { .. }, None) => Sampling::CoarseFine {
                coarse: 64,
                fine: 64,
            },
        }
    }

    /// Rays this step: fixed for coarse-to-fine, adapted to the sample budget when marching,
    /// rounded to the nearest size [bucket](ins_core::shape_buckets::bucket) so that the count
    /// repeats from step to step (GPU kernels are compiled per size; the CPU loses nothing).
    fn ray_count(&self) -> usize {
        match self.sampler {
            Sampler::Marching { target_samples, .. } => nearest_bucket(
                ((target_samples as f32 / self.samples_per_ray.max(1.0)) as usize)
                    .clamp(256, 1 << 16),
            ),
            Sampler::CoarseFine { rays, .. } => rays,
        }
    }

    fn pretrain_losses(&mut self, model: &NerfModel, seed: u64) -> Result<LossTerms> {
        let batch = RaySampler::new(self.ray_count(), seed).sample(&self.scene, Split::Train)?;
        let rays = RenderRays::from_batch(&self.scene, &batch);
        let r = batch.len();
        let target =
            Tensor::<1>::from_floats(batch.rgb.as_flattened(), &self.device).reshape([r, 3]);
        // Photos composited on white with an alpha mask (NeRF-synthetic) train against random
        // backgrounds, recomposited from the alpha: a field cannot then explain the white
        // background with colour instead of transparency (instant-ngp's trick).
        let random_background = self.scene.white_background
            && matches!(self.sampler, Sampler::Marching { .. })
            && self.scene.has_masks();
        let (pred, target, out) = if random_background {
            let mut rng = SmallRng::seed_from_u64(seed ^ 0xba5e_ba11);
            let bg: Vec<f32> = (0..r * 3).map(|_| rng.random::<f32>()).collect();
            let bg = Tensor::<1>::from_floats(bg.as_slice(), &self.device).reshape([r, 3]);
            let alpha =
                Tensor::<1>::from_floats(batch.mask.as_slice(), &self.device).reshape([r, 1]);
            let transparent = alpha.neg().add_scalar(1.0);
            let target = target + transparent * (bg.clone().sub_scalar(1.0));
            let out = render(
                model,
                &rays,
                self.sampling(),
                None,
                [0.0; 3],
                Some(seed),
                &self.device,
            );
            let rest = out
                .fine
                .opacity
                .clone()
                .neg()
                .add_scalar(1.0)
                .reshape([r, 1]);
            (out.fine.rgb.clone() + rest * bg, target, out)
        } else {
            // A learned background is composited here, over the field rendered on black.
            let out = render(
                model,
                &rays,
                self.sampling(),
                None,
                self.background.rendered_over(),
                Some(seed),
                &self.device,
            );
            let pred = self.background.composite_and_fit(
                out.fine.rgb.clone(),
                out.fine.opacity.clone(),
                target.clone(),
            );
            (pred, target, out)
        };
        self.last_samples = out.samples;
        self.last_rays = r;
        let mut terms = LossTerms::default()
            .term("mse", mse(pred, target.clone()))
            .metric_of("psnr", "mse", psnr)
            .metric("samples_per_ray", out.samples as f64 / batch.len() as f64)
            .metric("rays", batch.len() as f64);
        if let Some(c) = out.coarse_rgb {
            terms = terms.term("mse_coarse", mse(c, target));
        }
        Ok(terms)
    }

    fn stylize_losses(
        &mut self,
        model: &NerfModel,
        step: &StepContext<NerfObjective>,
    ) -> Result<LossTerms> {
        let seed = step.seed;
        let style = self
            .style
            .as_ref()
            .context("a stylization phase without styles")?;
        let spec = style.patch;
        let background = self.background.read();
        let style = self
            .style
            .as_ref()
            .context("a stylization phase without styles")?;
        let mut sampler = PatchSampler::new(spec.size, spec.stride, seed);
        let patch = sampler.sample(&self.scene, Split::Train)?;
        let k = spec.size as usize;
        let rays = RenderRays::from_batch(&self.scene, &patch.batch);
        let perceptual = &style.perceptual;
        let photo = photo_patch(&patch.batch.rgb, k, &self.device);
        let content_target = perceptual.content_target(photo.clone());
        let styles = perceptual.n_styles();
        let lr = step.phase.lr.at(step.step_in_phase);
        self.last_rays = k * k;
        if k * k > style.backprop_chunk {
            let patch_render = PatchRender {
                rays: &rays,
                sampling: self.sampling(),
                codes: &perceptual.codes,
                background,
                seed,
                chunk: style.backprop_chunk,
            };
            let weight = |term: &str| step.phase.weight_of(term);
            let mut terms = None;
            let mut probe = None;
            let loss = |pixels: Tensor<2>| {
                let images = patch_images(pixels, styles, k);
                probe = Some(perceptual.saturation_probe(images.clone(), photo.clone(), lr));
                let (s, c) = perceptual.terms(images, &content_target);
                let total =
                    s.clone().mul_scalar(weight("style")) + c.clone().mul_scalar(weight("content"));
                terms = Some((s.detach(), c.detach()));
                total
            };
            // The geometry term's mean over all samples, as each chunk's share of it.
            let mut geometry_sum = Tensor::<1>::zeros([1], &self.device);
            let geometry = |out: &Rendered, all: usize| {
                let teacher = style.teacher.as_ref()?;
                let share = out.samples as f32 / all.max(1) as f32;
                let mean = geometry_loss(teacher, out.points.clone(), out.raw.clone());
                geometry_sum = geometry_sum.clone() + mean.clone().detach().mul_scalar(share);
                Some(mean.mul_scalar(weight("geometry") * share as f64))
            };
            let (gradients, _, samples) =
                patch_render.backward(model, &self.device, loss, geometry);
            self.last_samples = samples;
            let (style_term, content_term) = terms.context("the loss was not evaluated")?;
            return Ok(LossTerms::default()
                .term("style", style_term)
                .term("content", content_term)
                .term("geometry", geometry_sum)
                .probe(probe.context("the loss was not evaluated")?)
                .with_gradients(gradients)
                .metric("samples_per_ray", samples as f64 / (k * k) as f64));
        }
        let out: Rendered = render(
            model,
            &rays,
            self.sampling(),
            Some(perceptual.codes.clone()),
            background,
            Some(seed),
            &self.device,
        );
        self.last_samples = out.samples;
        let images = patch_images(out.fine.rgb, styles, k);
        let probe = perceptual.saturation_probe(images.clone(), photo, lr);
        let (style_term, content_term) = perceptual.terms(images, &content_target);
        let geometry = match &style.teacher {
            Some(teacher) => geometry_loss(teacher, out.points, out.raw),
            None => Tensor::zeros([1], &self.device),
        };
        Ok(LossTerms::default()
            .term("style", style_term)
            .term("content", content_term)
            .term("geometry", geometry)
            .probe(probe)
            .metric(
                "samples_per_ray",
                self.last_samples as f64 / self.last_rays.max(1) as f64,
            ))
    }

    /// Refreshes the occupancy grid from the model's current density.
    pub fn refresh_grid(&mut self, model: &NerfModel, step: usize, seed: u64) {
        let Some(grid) = self.grid.as_mut() else {
            return;
        };
        let forward_facing = self.scene.forward_facing;
        let field = model.field.valid();
        let device = self.device.clone().inner();
        let density_at = |points: &[f32]| {
            let n = points.len() / 3;
            let mut out = Vec::with_capacity(n);
            for chunk in points.chunks(3 * 65536) {
                let m = chunk.len() / 3;
                let x = Tensor::<1>::from_floats(chunk, &device).reshape([m, 3]);
                out.extend(
                    field
                        .density(x)
                        .into_data()
                        .convert::<f32>()
                        .try_into_vec::<f32>()
                        .unwrap_or_else(|_| vec![0.0; m]),
                );
            }
            out
        };
        // During the warm-up the grid follows the field as it is: a running maximum there
        // kept the first steps' fog for ~700 steps on a room capture (27.05 dB at 1000 steps
        // rebuilt, 26.34 kept; lego 31.65 / 31.52). Forward-facing scenes (NDC) keep the
        // running maximum: there the rebuild cost 0.18 and 0.27 dB (fern, two seeds), their
        // fog clearing by step 400 either way (docs/measurements.md).
        if step >= WARMUP_STEPS {
            grid.update(grid.density.len() / REFRESH_SHARE, seed, density_at);
        } else if forward_facing {
            grid.update(usize::MAX, seed, density_at);
        } else {
            grid.rebuild(seed, density_at);
        }
    }

    fn evaluate(&self, model: &NerfModel, step: usize) -> Result<Vec<(String, f64)>> {
        let stylized = self.style.is_some();
        let model = model.valid();
        let device = self.device.clone().inner();
        let first_code = self.style.as_ref().map(|s| s.perceptual.first_code());
        let views = evaluate_views(
            &model,
            &self.scene,
            &self.eval.views,
            self.sampling(),
            first_code,
            self.background.now(),
            &device,
        )?;
        let pictures: Vec<RgbImage> = views.iter().map(|v| v.picture(&self.scene)).collect();
        save_eval_picture(
            &pictures,
            &self.eval.dir.join(format!("step_{step:06}.png")),
        )?;
        let mean = |f: fn(&super::eval::ViewEval) -> f64| {
            views.iter().map(f).sum::<f64>() / views.len().max(1) as f64
        };
        if stylized {
            return Ok(Vec::new());
        }
        Ok(vec![
            ("val_psnr".to_string(), mean(|v| v.psnr)),
            ("val_ssim".to_string(), mean(|v| v.ssim)),
        ])
    }
}

impl Task for NerfTask {
    type Model = NerfModel;
    type Objective = NerfObjective;

    fn terms(&self, objective: NerfObjective) -> &'static [&'static str] {
        match (objective, self.sampler) {
            (NerfObjective::Pretrain, Sampler::CoarseFine { .. }) => &["mse", "mse_coarse"],
            (NerfObjective::Pretrain, Sampler::Marching { .. }) => &["mse"],
            (NerfObjective::Stylize, _) => &["style", "content", "geometry"],
        }
    }

    fn losses(
        &mut self,
        model: &NerfModel,
        step: &StepContext<NerfObjective>,
    ) -> Result<LossTerms> {
        match step.phase.objective {
            NerfObjective::Pretrain => self.pretrain_losses(model, step.seed),
            NerfObjective::Stylize => self.stylize_losses(model, step),
        }
    }

    fn after_step(
        &mut self,
        model: &NerfModel,
        step: &StepContext<NerfObjective>,
    ) -> Result<Vec<(String, f64)>> {
        if self.last_rays > 0 {
            let per_ray = self.last_samples as f32 / self.last_rays as f32;
            self.samples_per_ray = 0.9 * self.samples_per_ray + 0.1 * per_ray.max(1.0);
        }
        if let Sampler::Marching { refresh_every, .. } = self.sampler
            && refresh_every > 0
            && step.phase.objective == NerfObjective::Pretrain
            && step.step_in_phase.is_multiple_of(refresh_every)
        {
            self.refresh_grid(model, step.step_in_phase, step.seed ^ 0x0cc0_9a1d);
        }
        let done = step.step_in_phase + 1;
        let mut logged = Vec::new();
        if step.phase.objective == NerfObjective::Pretrain && self.audit_at == Some(done) {
            let dropped = self.audit_views(model, step.seed ^ 0xa0d1_7000)?;
            logged.push(("dropped_views".to_string(), dropped as f64));
        }
        if self.eval.every > 0
            && done.is_multiple_of(self.eval.every)
            && !self.eval.views.is_empty()
        {
            logged.extend(self.evaluate(model, step.global_step + 1)?);
        }
        Ok(logged)
    }

    fn save_state(&self) -> Result<Option<Vec<u8>>> {
        Ok(Some(super::state_io::encode(&NerfState {
            samples_per_ray: self.samples_per_ray,
            grid: self.grid.clone(),
            background: self.background.sums(),
            dropped_views: self.dropped_views.clone(),
        })))
    }

    fn load_state(&mut self, bytes: &[u8]) -> Result<()> {
        let mut state = super::state_io::decode(bytes)?;
        self.samples_per_ray = state.samples_per_ray;
        if let Some(grid) = state.grid.take() {
            self.grid = Some(grid);
        }
        self.adopt(&state);
        Ok(())
    }
}
