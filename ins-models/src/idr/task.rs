//! The IDR task: pretraining a surface from masked photos (masked L1 colour, IDR's mask loss,
//! eikonal), or stylizing it on strided patches inside the mask with VGG losses.

use std::path::PathBuf;

use anyhow::{Context, Result};
use burn::prelude::*;
use ins_core::loss::{PerceptualLoss, patch_images, photo_patch, psnr};
use ins_core::render::sphere_tracing::TraceOptions;
use ins_core::shape_buckets::{pad_rows, padded_size, sum_counted};
use ins_core::train::{LossTerms, Probe, StepContext, Task};
use ins_scene::data::{Scene, Split};
use ins_scene::mask_sampler::MaskedPixels;
use ins_scene::patches::{PatchSampler, PatchSpec};
use ins_scene::rays::RaySampler;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::eval::{ViewOptions, evaluate_views, mean_scores, save_pictures};
use super::model::{IdrModel, SdfRenderer};
use super::render::render_surface;
use super::smoothness::gradient_change;
use super::volume::{VolumeSampling, background_colours, render_volume};

/// What a phase of an IDR run computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum IdrObjective {
    /// Masked colour, mask and eikonal losses on random rays.
    Pretrain,
    /// Style and content losses on strided patches inside the mask.
    Stylize,
}

/// Fraction of a stylization patch that must lie inside the mask: the black background is
/// not the surface's to paint, and a patch that is half background has a Gram matrix no
/// colour of the surface can bring to the painting's.
pub const PATCH_COVERAGE: f32 = 0.9;

/// Share of pretraining during which a volume run without masks holds its sharpness. The
/// colour loss first wants the starting sphere gone wherever the background shows through it,
/// and blurring the sphere is the quickest way there: scan37 through SfM without masks, its
/// starting sphere much over the table, had its sharpness fall from 20 to 0.1 in 70 steps and
/// crawl back (0.13 at step 300). Held, the SDF carves instead. With masks, the mask term
/// carves from the first step.
const SHARPNESS_HOLD: f32 = 0.1;

/// `model` with its sharpness held where it is (no gradient reaches it).
fn with_sharpness_held(model: &IdrModel) -> IdrModel {
    let mut held = model.clone();
    held.sharpness = held.sharpness.map(|s| s.no_grad());
    held
}

/// What stylization needs.
pub struct SurfaceStylization {
    /// VGG, the paintings' targets and the style codes.
    pub perceptual: PerceptualLoss,
    /// Patch geometry.
    pub patch: PatchSpec,
}

/// The task.
pub struct IdrTask {
    /// The scene (masks included unless trained with `--no-mask`).
    pub scene: Scene,
    /// Rays per pretraining step.
    pub rays: usize,
    /// Random points per pretraining step for the eikonal loss.
    pub eikonal_points: usize,
    /// Steps of the pretraining phase (the mask loss sharpens over them).
    pub steps: usize,
    /// Whether masks are used.
    pub masked: bool,
    /// Stylization, when stylizing.
    pub style: Option<SurfaceStylization>,
    /// Steps between evaluations (0: never during training).
    pub eval_every: usize,
    /// Held-out views to evaluate.
    pub eval_views: Vec<usize>,
    /// Where evaluation pictures go.
    pub eval_dir: PathBuf,
    /// Ray tracer settings.
    pub trace: TraceOptions,
    /// Pretraining rays drawn inside the masks: the share and the index of mask pixels.
    pub mask_rays: Option<(f32, MaskedPixels)>,
    /// How pretraining renders the SDF.
    pub renderer: SdfRenderer,
    /// The volume renderer's samples.
    pub sampling: VolumeSampling,
    /// Samples near the surface per step where the smoothness term compares the SDF's
    /// gradient with its value a small step away (0: no such term).
    pub curvature_points: usize,
    device: Device,
}

impl IdrTask {
    /// A task on `scene`, computing on `device` (an autodiff device).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        scene: Scene,
        rays: usize,
        steps: usize,
        masked: bool,
        style: Option<SurfaceStylization>,
        eval_every: usize,
        eval_views: Vec<usize>,
        eval_dir: PathBuf,
        device: &Device,
    ) -> Self {
        Self {
            scene,
            rays,
            eikonal_points: 2048,
            steps,
            masked,
            style,
            eval_every,
            eval_views,
            eval_dir,
            trace: TraceOptions::default(),
            mask_rays: None,
            renderer: SdfRenderer::Surface,
            sampling: VolumeSampling::default(),
            curvature_points: 0,
            device: device.clone(),
        }
    }

    /// How evaluation renders whole views: the task's tracer and volume samples.
    pub fn view_options(&self) -> ViewOptions {
        ViewOptions {
            trace: self.trace,
            sampling: self.sampling,
        }
    }

    /// Draws `share` of each pretraining batch from inside the masks (0 or no masks: uniform).
    pub fn with_mask_rays(mut self, share: f32) -> Result<Self> {
        self.mask_rays = if self.masked && share > 0.0 {
            Some((share, MaskedPixels::new(&self.scene, Split::Train)?))
        } else {
            None
        };
        Ok(self)
    }

    /// IDR's mask sharpness α: 50, doubling at each fifth of pretraining (up to 1600).
    pub fn alpha(&self, step: usize) -> f32 {
        let fifth = (self.steps / 5).max(1);
        50.0 * 2f32.powi((step / fifth).min(5) as i32)
    }

    /// A pretraining batch of rays: `mask_rays`'s share inside the masks, the rest uniform;
    /// with that share, each ray's weight in the mask term
    /// ([`MaskedPixels::uniform_weights`]: the silhouette as uniform rays would set it).
    fn pretrain_batch(&self, seed: u64) -> Result<(ins_scene::rays::RayBatch, Option<Vec<f32>>)> {
        Ok(match &self.mask_rays {
            Some((share, index)) => {
                let batch = index.sample(&self.scene, self.rays, *share, seed)?;
                let weights = index.uniform_weights(&self.scene, &batch, *share);
                (batch, Some(weights))
            }
            None => (
                RaySampler::new(self.rays, seed).sample(&self.scene, Split::Train)?,
                None,
            ),
        })
    }

    /// Pretraining through the volume renderer: L1 colour over the mask's rays (black
    /// elsewhere), the opacity's cross-entropy against the mask, eikonal on every sample.
    fn pretrain_volume_losses(
        &self,
        model: &IdrModel,
        step: usize,
        seed: u64,
    ) -> Result<LossTerms> {
        let held;
        let model = if !self.masked && (step as f32) < SHARPNESS_HOLD * self.steps as f32 {
            held = with_sharpness_held(model);
            &held
        } else {
            model
        };
        let (batch, mask_weights) = self.pretrain_batch(seed)?;
        let r = batch.len();
        let out = render_volume(
            model,
            &batch.rays,
            None,
            [0.0; 3],
            &self.sampling,
            Some(seed),
            &self.device,
        );
        let mask: Vec<f32> = if self.masked {
            batch.mask.clone()
        } else {
            vec![1.0; r]
        };
        let inside: Vec<f32> = mask.iter().map(|&m| (m > 0.5) as u8 as f32).collect();
        let count = inside.iter().sum::<f32>().max(1.0);
        let inside_t = Tensor::<1>::from_floats(inside.as_slice(), &self.device).reshape([r, 1]);
        let target =
            Tensor::<1>::from_floats(batch.rgb.as_flattened(), &self.device).reshape([r, 3]);
        let diff = (out.rgb - target) * inside_t.clone();
        let rgb_loss = diff.clone().abs().sum().div_scalar(count);
        let mse_in = diff.square().sum().div_scalar(count * 3.0);
        let opacity = out.opacity.clone();
        let mut terms = LossTerms::default()
            .term("rgb", rgb_loss)
            .term("mse_mask", mse_in)
            .metric_of("psnr_mask", "mse_mask", psnr);
        if let Some(sharp) = &model.sharpness {
            // Read with the terms, not on its own: a read of its own would make a GPU wait.
            terms = terms.probe(Probe {
                name: "sharpness",
                value: sharp.s().detach(),
                watch: None,
            });
        }
        if self.masked {
            let gt = Tensor::<1>::from_floats(inside.as_slice(), &self.device);
            let o = opacity.clamp(1e-3, 1.0 - 1e-3);
            let bce = (gt.clone() * o.clone().log()
                + gt.neg().add_scalar(1.0) * o.neg().add_scalar(1.0).log())
            .neg();
            let bce = match mask_weights {
                Some(w) => {
                    let total = w.iter().sum::<f32>().max(f32::MIN_POSITIVE);
                    (bce * Tensor::<1>::from_floats(w.as_slice(), &self.device))
                        .sum()
                        .div_scalar(total)
                }
                None => bce.mean(),
            };
            terms = terms.term("mask", bce);
        }
        // Eikonal: every sample inside the unit sphere, and random points of its box.
        let Some(gradients) = out.gradients.clone() else {
            anyhow::bail!("a training render carries every sample's gradient");
        };
        let per_sample = gradients
            .clone()
            .square()
            .sum_dim(1)
            .sqrt()
            .sub_scalar(1.0)
            .square()
            .reshape([out.live.dims()[0]])
            * out.live;
        let mut eik = per_sample.sum();
        let mut counted = out.live_count;
        if let Some(g) = self.random_gradients(model, seed) {
            let rows = g.dims()[0];
            eik = eik
                + g.square()
                    .sum_dim(1)
                    .sqrt()
                    .sub_scalar(1.0)
                    .square()
                    .reshape([rows])
                    .sum();
            counted += rows;
        }
        let terms = terms.term("eikonal", eik.div_scalar(counted.max(1) as f32));
        Ok(match self.curvature_points {
            0 => terms,
            k => terms.term(
                "curvature",
                gradient_change(model, &out.points, &gradients, &out.seen, k, seed),
            ),
        })
    }

    /// The SDF's gradient at `eikonal_points` random points of the unit sphere's box.
    fn random_gradients(&self, model: &IdrModel, seed: u64) -> Option<Tensor<2>> {
        let mut rng = SmallRng::seed_from_u64(seed ^ 0xe1c0);
        let k = self.eikonal_points;
        let pts: Vec<f32> = (0..k * 3)
            .map(|_| rng.random::<f32>() * 2.0 - 1.0)
            .collect();
        (k > 0).then(|| {
            let x = Tensor::<1>::from_floats(pts.as_slice(), &self.device).reshape([k, 3]);
            model.sdf.forward_with_gradient(x).2
        })
    }

    fn pretrain_losses(&self, model: &IdrModel, step: usize, seed: u64) -> Result<LossTerms> {
        if self.renderer == SdfRenderer::Volume {
            return self.pretrain_volume_losses(model, step, seed);
        }
        let (batch, mask_weights) = self.pretrain_batch(seed)?;
        let r = batch.len();
        let out = render_surface(
            model,
            &batch.rays,
            None,
            [0.0; 3],
            &self.trace,
            true,
            &self.device,
        );
        let mask: Vec<f32> = if self.masked {
            batch.mask.clone()
        } else {
            vec![1.0; r]
        };
        // Colour: L1 over rays that hit inside the mask, normalised by all rays (IDR).
        let inside: Vec<f32> = (0..r)
            .map(|i| {
                if out.traced.hit[i] && mask[i] > 0.5 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let inside_t = Tensor::<1>::from_floats(inside.as_slice(), &self.device).reshape([r, 1]);
        let target =
            Tensor::<1>::from_floats(batch.rgb.as_flattened(), &self.device).reshape([r, 3]);
        let rgb = (out.rgb.clone() - target.clone()).abs() * inside_t.clone();
        let rgb_loss = rgb.sum().div_scalar(r as f32);
        // Logged only (weight 0): the MSE inside the mask, read with the other terms.
        let mse_in = ((out.rgb - target).square() * inside_t)
            .sum()
            .div_scalar((inside.iter().sum::<f32>() * 3.0).max(1.0));
        let mut terms = LossTerms::default()
            .term("rgb", rgb_loss)
            .term("mse_mask", mse_in)
            .metric_of("psnr_mask", "mse_mask", psnr)
            .metric("hit_rate", out.hits.len() as f64 / r as f64)
            .metric("trace_ms", out.trace_ms);
        // Mask: soft occupancy at the surface point (hits outside the mask) or at the point of
        // smallest SDF (misses), BCE against the mask, scaled by 1/α.
        if self.masked {
            let alpha = self.alpha(step);
            let outside: Vec<usize> = (0..r).filter(|&i| inside[i] == 0.0).collect();
            if !outside.is_empty() {
                let pts: Vec<f32> = outside
                    .iter()
                    .flat_map(|&i| {
                        let t = if out.traced.hit[i] {
                            out.traced.t[i]
                        } else {
                            out.traced.t_min_sdf[i]
                        };
                        batch.rays.point(i, t).to_array()
                    })
                    .collect();
                // Padded to a bucketed count on GPUs; padding weighs nothing.
                let m = padded_size(outside.len(), &self.device);
                let mut pts = pts;
                pad_rows(&mut pts, 3, m);
                let mut gt: Vec<f32> = outside.iter().map(|&i| mask[i]).collect();
                gt.resize(m, 0.0);
                let x = Tensor::<1>::from_floats(pts.as_slice(), &self.device).reshape([m, 3]);
                let s = model.sdf.sdf(x);
                let logits = s.mul_scalar(-alpha);
                let gt = Tensor::<1>::from_floats(gt.as_slice(), &self.device);
                // BCE with logits, stable form: max(z, 0) − z·y + log(1 + e^{−|z|}).
                let bce = logits.clone().clamp_min(0.0) - logits.clone() * gt
                    + logits.abs().neg().exp().add_scalar(1.0).log();
                let bce = match &mask_weights {
                    // Padding weighs nothing here too.
                    Some(w) => {
                        let mut wo: Vec<f32> = outside.iter().map(|&i| w[i]).collect();
                        wo.resize(m, 0.0);
                        let mean_weight = w.iter().sum::<f32>() / r as f32;
                        (bce.reshape([m]) * Tensor::<1>::from_floats(wo.as_slice(), &self.device))
                            .sum()
                            .div_scalar(mean_weight.max(f32::MIN_POSITIVE))
                    }
                    None => sum_counted(bce.reshape([m]), outside.len()),
                };
                terms = terms.term("mask", bce.div_scalar(alpha * r as f32));
            } else {
                terms = terms.term("mask", Tensor::<1>::zeros([1], &self.device));
            }
        }
        // Eikonal: |∇f| = 1 at random points of the unit sphere's box and at the surface points.
        let k = self.eikonal_points;
        let random = self.random_gradients(model, seed);
        // Rows past the hits in the surface gradients are GPU padding, left out of the sum.
        let counted = k + out.hits.len();
        let gradients: Vec<Tensor<2>> = random.into_iter().chain(out.surface_gradients).collect();
        let eik = if gradients.is_empty() {
            Tensor::<1>::zeros([1], &self.device)
        } else {
            let g = Tensor::cat(gradients, 0);
            let rows = g.dims()[0];
            let per_point = g.square().sum_dim(1).sqrt().sub_scalar(1.0).square();
            sum_counted(per_point.reshape([rows]), counted).div_scalar(counted as f32)
        };
        Ok(terms.term("eikonal", eik))
    }

    fn stylize_losses(&self, model: &IdrModel, seed: u64, lr: f64) -> Result<LossTerms> {
        let style = self
            .style
            .as_ref()
            .context("a stylization phase without styles")?;
        let mut sampler = PatchSampler::new(style.patch.size, style.patch.stride, seed);
        sampler = if self.masked {
            sampler.with_min_coverage(PATCH_COVERAGE)
        } else {
            // A run without masks does not read them here either: the first patch drawn.
            sampler.max_redraws = 0;
            sampler
        };
        let patch = sampler.sample(&self.scene, Split::Train)?;
        let k = style.patch.size as usize;
        let perceptual = &style.perceptual;
        let out = render_surface(
            model,
            &patch.batch.rays,
            Some(perceptual.codes.clone()),
            [0.0; 3],
            &self.trace,
            true,
            &self.device,
        );
        let styles = perceptual.n_styles();
        // Behind the surface, what the photo shows there: the field beyond the unit sphere of a
        // run without masks (fixed: the surface's colours are what stylizes), black with masks.
        let rgb = match background_colours(model, &patch.batch.rays, &self.device) {
            Some(behind) if !self.masked => {
                let n = k * k;
                let miss: Vec<f32> = out.traced.hit.iter().map(|&h| (!h) as u8 as f32).collect();
                let miss = Tensor::<1>::from_floats(miss.as_slice(), &self.device).reshape([n, 1]);
                let back = (behind.detach() * miss.expand([n, 3]))
                    .reshape([1, n, 3])
                    .expand([styles, n, 3])
                    .reshape([styles * n, 3]);
                out.rgb + back
            }
            _ => out.rgb,
        };
        let images = patch_images(rgb, styles, k);
        // The photo inside its mask, on the same black background as the render.
        let photo: Vec<[f32; 3]> = if self.masked {
            patch
                .batch
                .rgb
                .iter()
                .zip(&patch.batch.mask)
                .map(|(c, m)| c.map(|v| v * m))
                .collect()
        } else {
            patch.batch.rgb.clone()
        };
        let photo = photo_patch(&photo, k, &self.device);
        let probe = perceptual.saturation_probe(images.clone(), photo.clone(), lr);
        let content_target = perceptual.content_target(photo);
        let (style_term, content_term) = perceptual.terms(images, &content_target);
        Ok(LossTerms::default()
            .term("style", style_term)
            .term("content", content_term)
            .probe(probe)
            .metric("hit_rate", out.hits.len() as f64 / (k * k) as f64)
            .metric("trace_ms", out.trace_ms))
    }
}

impl Task for IdrTask {
    type Model = IdrModel;
    type Objective = IdrObjective;

    fn terms(&self, objective: IdrObjective) -> &'static [&'static str] {
        match (objective, self.masked) {
            (IdrObjective::Pretrain, true) => &["rgb", "mse_mask", "mask", "eikonal", "curvature"],
            (IdrObjective::Pretrain, false) => &["rgb", "mse_mask", "eikonal", "curvature"],
            (IdrObjective::Stylize, _) => &["style", "content"],
        }
    }

    fn losses(&mut self, model: &IdrModel, step: &StepContext<IdrObjective>) -> Result<LossTerms> {
        match step.phase.objective {
            IdrObjective::Pretrain => self.pretrain_losses(model, step.step_in_phase, step.seed),
            IdrObjective::Stylize => {
                self.stylize_losses(model, step.seed, step.phase.lr.at(step.step_in_phase))
            }
        }
    }

    fn after_step(
        &mut self,
        model: &IdrModel,
        step: &StepContext<IdrObjective>,
    ) -> Result<Vec<(String, f64)>> {
        let done = step.step_in_phase + 1;
        if self.eval_every == 0
            || !done.is_multiple_of(self.eval_every)
            || self.eval_views.is_empty()
        {
            return Ok(Vec::new());
        }
        let m = model.valid();
        let device = self.device.clone().inner();
        let code = self.style.as_ref().map(|s| s.perceptual.first_code());
        let evals = evaluate_views(
            &m,
            &self.scene,
            &self.eval_views,
            code,
            &self.view_options(),
            &device,
        )?;
        save_pictures(
            &evals,
            &self
                .eval_dir
                .join(format!("step_{:06}.png", step.global_step + 1)),
        )?;
        let means = mean_scores(&evals);
        Ok(["iou", "psnr_mask"]
            .into_iter()
            .map(|k| (format!("val_{k}"), means[k]))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::idr::model::IdrArch;
    use ins_core::modules::sdf::SdfNet;

    /// A held sharpness gets no gradient; the SDF rendered with it still does.
    #[test]
    fn a_held_sharpness_gets_no_gradient() {
        let device = Device::flex().autodiff();
        let arch = IdrArch {
            grid_max_resolution: 32,
            color_width: 8,
            ..IdrArch::small_volume()
        };
        let model = IdrModel::new(&arch, &device);
        let held = with_sharpness_held(&model);
        let x = Tensor::<2>::from_floats([[0.1, 0.2, 0.3], [0.5, 0.0, 0.0]], &device);
        let sharp = held.sharpness.as_ref().unwrap();
        let loss = held.sdf.sdf(x).sum() * sharp.s();
        let grads = loss.backward();
        let own = model.sharpness.as_ref().unwrap();
        assert!(own.variance.val().grad(&grads).is_none());
        assert!(sharp.variance.val().grad(&grads).is_none());
        let SdfNet::Grid(grid) = &held.sdf else {
            panic!("a grid SDF")
        };
        assert!(grid.grid.table.val().grad(&grads).is_some());
    }
}
