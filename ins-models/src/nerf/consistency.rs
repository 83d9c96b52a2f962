//! The evaluation of a stylized NeRF along a camera path: view consistency (frames warped into
//! their neighbours by the pretrained depth), Gram distance to the painting and content
//! distance to the pretrained render per view, and the depth kept from pretraining. Any set of
//! frames of the same path (the stylized run, the pretrained run, a per-view 2D baseline) is
//! scored on the same pixels.

use anyhow::Result;
use burn::prelude::*;
use ins_core::eval::consistency::{PairScore, PathGeometry, mean_rmse};
use ins_core::imaging::RgbImage;
use ins_core::loss::{content_loss, style_loss};
use ins_core::render::camera::Camera;
use serde::Serialize;
use vgg_import::Vgg;

use super::eval::{ViewRender, depth_agreement, render_camera};
use super::run::NerfRun;

/// The ranges scored: short (neighbouring frames) and long (seven frames apart).
pub const RANGES: [usize; 2] = [1, 7];

/// A path rendered by the pretrained model (the geometry) and by the stylized one.
pub struct PathRenders {
    /// One camera per frame.
    pub cameras: Vec<Camera>,
    /// Unstylized renders of the pretrained (teacher) run.
    pub pretrained: Vec<ViewRender>,
    /// Renders of the stylized run.
    pub stylized: Vec<ViewRender>,
}

impl PathRenders {
    /// Renders `cameras` with `teacher` (pretrained) and `student` (stylized, under `code`),
    /// calling `progress(done)` after each frame.
    pub fn render(
        student: &NerfRun,
        teacher: &NerfRun,
        cameras: Vec<Camera>,
        code: Option<Tensor<2>>,
        device: &Device,
        mut progress: impl FnMut(usize),
    ) -> Result<Self> {
        let (s_model, t_model) = (student.model.valid(), teacher.model.valid());
        let mut pretrained = Vec::with_capacity(cameras.len());
        let mut stylized = Vec::with_capacity(cameras.len());
        for (i, cam) in cameras.iter().enumerate() {
            pretrained.push(render_camera(
                &t_model,
                &teacher.scene,
                cam,
                teacher.sampling(),
                None,
                teacher.background(),
                device,
            )?);
            stylized.push(render_camera(
                &s_model,
                &student.scene,
                cam,
                student.sampling(),
                code.clone(),
                student.background(),
                device,
            )?);
            progress(i + 1);
        }
        Ok(Self {
            cameras,
            pretrained,
            stylized,
        })
    }

    /// The path's geometry: the pretrained model's surface points.
    pub fn geometry(&self, teacher: &NerfRun) -> PathGeometry {
        PathGeometry {
            cameras: self.cameras.clone(),
            points: self
                .cameras
                .iter()
                .zip(&self.pretrained)
                .map(|(c, r)| r.surface_points(&teacher.scene, c))
                .collect(),
        }
    }

    /// Median relative depth error of the stylized renders against the pretrained ones on
    /// pixels opaque in both (mean over frames), and the fraction of pixels whose opacity
    /// agrees (both above or both below 0.5).
    pub fn depth_agreement(&self) -> (f64, f64) {
        let n = self.cameras.len().max(1) as f64;
        let (mut err, mut agree) = (0.0, 0.0);
        for (s, t) in self.stylized.iter().zip(&self.pretrained) {
            let (e, a, _) = depth_agreement(s, t);
            err += e;
            agree += a;
        }
        (err / n, agree / n)
    }
}

/// How one set of frames scores.
#[derive(Debug, Clone, Serialize)]
pub struct SetScores {
    /// `stylized`, `baseline2d` or `pretrained`.
    pub set: String,
    /// Per range in [`RANGES`]: the mean masked RMSE.
    pub rmse: Vec<Option<f64>>,
    /// Per range: every pair.
    #[serde(skip)]
    pub pairs: Vec<Vec<PairScore>>,
    /// Per view: Gram distance to the painting (relu1_2…relu4_3, the training loss).
    pub gram_distance: Vec<f64>,
    /// Per view: relu2_2 content distance to the pretrained render of the view.
    pub content_distance: Vec<f64>,
}

impl SetScores {
    /// Mean Gram distance over the views.
    pub fn mean_gram(&self) -> f64 {
        mean(&self.gram_distance)
    }

    /// Mean content distance over the views.
    pub fn mean_content(&self) -> f64 {
        mean(&self.content_distance)
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The relu2_2 features of `frames`: the content reference of every set scored against them.
pub fn content_features(vgg: &Vgg, frames: &[RgbImage], device: &Device) -> Vec<Tensor<4>> {
    frames
        .iter()
        .map(|f| vgg.features(f.to_tensor(device)).relu2_2)
        .collect()
}

/// Scores `frames` of the path: consistency at every range, and per view the style and
/// content distances (`style` the painting's Gram targets, `reference` the pretrained frames'
/// relu2_2 features), one VGG pass per frame.
pub fn score_frames(
    set: &str,
    geometry: &PathGeometry,
    frames: &[RgbImage],
    reference: &[Tensor<4>],
    vgg: &Vgg,
    style: &[Tensor<3>; 4],
    device: &Device,
) -> SetScores {
    let data: Vec<&[f32]> = frames.iter().map(|f| f.data.as_slice()).collect();
    let pairs: Vec<Vec<PairScore>> = RANGES
        .iter()
        .map(|&k| geometry.pair_scores(&data, k))
        .collect();
    let mut gram = Vec::with_capacity(frames.len());
    let mut content = Vec::with_capacity(frames.len());
    for (f, r) in frames.iter().zip(reference) {
        let feats = vgg.features(f.to_tensor(device));
        gram.push(style_loss(&feats, style).into_scalar::<f32>() as f64);
        content.push(content_loss(&feats, r).into_scalar::<f32>() as f64);
    }
    SetScores {
        set: set.to_string(),
        rmse: pairs.iter().map(|p| mean_rmse(p)).collect(),
        pairs,
        gram_distance: gram,
        content_distance: content,
    }
}
