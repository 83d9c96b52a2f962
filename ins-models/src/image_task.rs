//! The image task shared by every coordinate → RGB representation: fit the content image with
//! pixel MSE, then stylize through VGG style and content losses on strided patches.
//!
//! A K×K patch with stride s covers a (K·s)×(K·s) window of the image, so VGG sees a large
//! receptive field at the cost of K² coordinates (the sampling-stride idea of INS). Every
//! step renders the same patch under all styles (one-hot codes), so one content pass serves
//! all of them.

use std::collections::HashMap;

use anyhow::Result;
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{ContentTarget, PerceptualLoss, mse, patch_images, psnr};
use ins_core::modules::cim::ContentModule;
use ins_core::modules::ins::Ins;
use ins_core::train::{LossTerms, StepContext, Task};
use ins_scene::data::plain_image::pixel_coordinates;
use ins_scene::patches::PatchSpec;
use rand::Rng;
use rand::SeedableRng;
use rand::rngs::SmallRng;
use serde::{Deserialize, Serialize};

/// What a phase of the image task computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageObjective {
    /// Pixel MSE on random batches: reconstruct the content.
    Fit,
    /// VGG style and content losses on strided patches, every style at once.
    Stylize,
}

/// Renders `model` at `w`×`h` under style code `code` (length `n_styles`), in chunks.
pub fn render_image<C: ContentModule>(
    model: &Ins<C>,
    w: usize,
    h: usize,
    code: &[f32],
    device: &Device,
) -> Result<RgbImage> {
    render_window(model, w, h, 0..h, [0.0, 0.0], 1.0, code, device)
}

/// Rows `rows` of a `w`×`h` view of `model` centred on `center` and magnified `zoom` times
/// (pixel coordinates `center + c / zoom`, `c` in `[-1, 1]²`): the viewer's pan and zoom.
#[allow(clippy::too_many_arguments)]
pub fn render_window<C: ContentModule>(
    model: &Ins<C>,
    w: usize,
    h: usize,
    rows: std::ops::Range<usize>,
    center: [f32; 2],
    zoom: f32,
    code: &[f32],
    device: &Device,
) -> Result<RgbImage> {
    let all = pixel_coordinates(w as u32, h as u32);
    let coords: Vec<f32> = all[rows.start * w..rows.end.min(h) * w]
        .iter()
        .flat_map(|c| [center[0] + c[0] / zoom, center[1] + c[1] / zoom])
        .collect();
    let code = Tensor::<2>::from_data(TensorData::new(code.to_vec(), [1, code.len()]), device);
    let chunk = 32768;
    let n = coords.len() / 2;
    let mut data = Vec::with_capacity(n * 3);
    let mut start = 0;
    while start < n {
        let len = chunk.min(n - start);
        let c = Tensor::<2>::from_data(
            TensorData::new(coords[start * 2..(start + len) * 2].to_vec(), [len, 2]),
            device,
        );
        let rgb = model.forward(c, code.clone());
        let v = rgb
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("reading render: {e:?}"))?;
        data.extend(v);
        start += len;
    }
    Ok(RgbImage {
        width: w,
        height: n / w.max(1),
        data,
    })
}

/// The image task of a content module `C`: content, the styles' loss and batch settings.
pub struct ImageTask<C> {
    device: Device,
    content: RgbImage,
    content_tensor: Tensor<2>,
    coords: Vec<f32>,
    perceptual: PerceptualLoss,
    fit_batch: usize,
    patch: PatchSpec,
    content_cache: HashMap<(u32, u32), ContentTarget>,
    _model: std::marker::PhantomData<C>,
}

impl<C: ContentModule> ImageTask<C> {
    /// Prepares the task: content at its training size and the styles' loss, on `device`. The
    /// patch shrinks to fit the content; a stride too large for it is an error.
    pub fn new(
        content: RgbImage,
        perceptual: PerceptualLoss,
        fit_batch: usize,
        patch: PatchSpec,
        device: &Device,
    ) -> Result<Self> {
        let patch = patch.fitted(content.width as u32, content.height as u32)?;
        let content_tensor = Tensor::<1>::from_data(
            TensorData::new(content.data.clone(), [content.data.len()]),
            device,
        )
        .reshape([content.width * content.height, 3]);
        Ok(Self {
            device: device.clone(),
            coords: pixel_coordinates(content.width as u32, content.height as u32).into_flattened(),
            content,
            content_tensor,
            perceptual,
            fit_batch,
            patch,
            content_cache: HashMap::new(),
            _model: std::marker::PhantomData,
        })
    }

    /// The patch actually used (fitted to the content).
    pub fn patch(&self) -> PatchSpec {
        self.patch
    }

    fn gather(&self, idx: &[usize]) -> (Tensor<2>, Tensor<2>) {
        let mut c = Vec::with_capacity(idx.len() * 2);
        for &i in idx {
            c.push(self.coords[2 * i]);
            c.push(self.coords[2 * i + 1]);
        }
        let coords = Tensor::from_data(TensorData::new(c, [idx.len(), 2]), &self.device);
        let ids: Vec<i64> = idx.iter().map(|&i| i as i64).collect();
        let ids = Tensor::<1, Int>::from_data(TensorData::new(ids, [idx.len()]), &self.device);
        (coords, self.content_tensor.clone().select(0, ids))
    }

    fn fit_losses(&self, model: &Ins<C>, seed: u64) -> Result<LossTerms> {
        let n = self.content.width * self.content.height;
        let mut rng = SmallRng::seed_from_u64(seed);
        let idx: Vec<usize> = if self.fit_batch >= n {
            (0..n).collect()
        } else {
            (0..self.fit_batch)
                .map(|_| rng.random_range(0..n))
                .collect()
        };
        let (coords, target) = self.gather(&idx);
        // The fitting phase freezes SIM and AM (see `SirenRunConfig::phases`): the AM stays the
        // identity, so the content path alone renders what every style starts from.
        let loss = mse(model.forward_content(coords), target);
        Ok(LossTerms::default()
            .term("mse", loss)
            .metric_of("psnr", "mse", psnr))
    }

    fn stylize_losses(&mut self, model: &Ins<C>, seed: u64, lr: f64) -> Result<LossTerms> {
        let (w, h) = (self.content.width as u32, self.content.height as u32);
        let mut rng = SmallRng::seed_from_u64(seed);
        let (x0, y0) = self.patch.random_origin(w, h, &mut rng)?;
        let k = self.patch.size as usize;
        let idx: Vec<usize> = self
            .patch
            .pixels(x0, y0)
            .map(|(x, y)| y as usize * w as usize + x as usize)
            .collect();
        let (coords, target) = self.gather(&idx);
        let target_key = (x0, y0);
        let photo = patch_images(target, 1, k).detach();
        let content_target = match self.content_cache.get(&target_key) {
            Some(t) => t.clone(),
            None => {
                let t = self.perceptual.content_target(photo.clone());
                if self.content_cache.len() < 256 {
                    self.content_cache.insert(target_key, t.clone());
                }
                t
            }
        };
        let perceptual = &self.perceptual;
        let rgb = model.forward(coords, perceptual.codes.clone());
        let images = patch_images(rgb, perceptual.n_styles(), k);
        let probe = perceptual.saturation_probe(images.clone(), photo, lr);
        let (style, content) = perceptual.terms(images, &content_target);
        Ok(LossTerms::default()
            .term("style", style)
            .term("content", content)
            .probe(probe))
    }
}

impl<C: ContentModule> Task for ImageTask<C> {
    type Model = Ins<C>;
    type Objective = ImageObjective;

    fn terms(&self, objective: ImageObjective) -> &'static [&'static str] {
        match objective {
            ImageObjective::Fit => &["mse"],
            ImageObjective::Stylize => &["style", "content"],
        }
    }

    fn losses(&mut self, model: &Ins<C>, step: &StepContext<ImageObjective>) -> Result<LossTerms> {
        match step.phase.objective {
            ImageObjective::Fit => self.fit_losses(model, step.seed),
            ImageObjective::Stylize => {
                self.stylize_losses(model, step.seed, step.phase.lr.at(step.step_in_phase))
            }
        }
    }
}
