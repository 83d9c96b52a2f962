//! A stylized run evaluated along a camera path, whichever variant renders it (NeRF, IDR):
//! view consistency (frames warped into their neighbours by the pretrained geometry), per view
//! the Gram distance to the painting and the content distance to the pretrained render, and
//! the depth kept from pretraining. Any set of frames of the same path (the stylized run, the
//! pretrained run, a per-view 2D baseline) is scored on the same pixels.
//!
//! - [`evaluate`]: the whole evaluation of a stylized run, written into one folder;
//! - [`texture_table`]: the painting's texture on the object per set of frames.

pub mod evaluate;
pub mod texture_table;

pub use evaluate::{ConsistencyOptions, Evaluation, Progress, evaluate};

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::eval::consistency::{PairScore, PathGeometry, mean_rmse};
use ins_core::eval::depth::DepthAgreement;
use ins_core::imaging::RgbImage;
use ins_core::loss::{content_loss, style_loss};
use ins_scene::camera::Camera;
use ins_scene::paths::{PathKind, path_for_scene};
use serde::Serialize;
use vgg_import::Vgg;

use crate::run::any::load_scene_run;
use crate::run::scene_render::{PathFrame, SceneRender};

/// The ranges scored: short (neighbouring frames) and long (seven frames apart).
pub const RANGES: [usize; 2] = [1, 7];

/// What the evaluation does, for the error a SIREN run gets.
const WHAT: &str = "view consistency";

/// A stylized run folder and its pretrained run, of either variant.
pub struct StylizedPair {
    /// The stylized run.
    pub student: Box<dyn SceneRender>,
    /// The pretrained run it started from.
    pub teacher: Box<dyn SceneRender>,
}

impl StylizedPair {
    /// Loads the stylized run `dir` (NeRF or IDR, told apart by its config) and its base.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let student = load_scene_run(dir, device, WHAT)?;
        let Some(from) = student.base_run().map(Path::to_path_buf) else {
            bail!(
                "{} is a pretrained run: view consistency is measured on a stylized run \
                 (`ins-cli train nerf|idr --from {} --style PAINTING`)",
                dir.display(),
                dir.display()
            );
        };
        let teacher = load_scene_run(&from, device, WHAT)?;
        Ok(Self { student, teacher })
    }

    /// The painting of style `style` (an index into the run's `--style` list).
    pub fn painting(&self, style: usize) -> Result<&Path> {
        let styles = &self.student.style().styles;
        styles.get(style).map(PathBuf::as_path).with_context(|| {
            format!(
                "--style {style}: {} has {} style{}",
                self.student.dir().display(),
                styles.len(),
                if styles.len() == 1 { "" } else { "s" }
            )
        })
    }

    /// The default path ([`ins_scene::paths::default_kind`]).
    pub fn default_path(&self) -> PathKind {
        ins_scene::paths::default_kind(self.student.scene())
    }

    /// The cameras of a `kind` path (default: [`StylizedPair::default_path`]) of `frames`.
    pub fn cameras(&self, kind: Option<PathKind>, frames: usize) -> Result<Vec<Camera>> {
        let scene = self.student.scene();
        path_for_scene(scene, kind, frames).context("the scene has no cameras to build a path from")
    }
}

/// A path rendered by the pretrained model (the geometry) and by the stylized one.
pub struct PathRenders {
    /// One camera per frame.
    pub cameras: Vec<Camera>,
    /// Unstylized frames of the pretrained (teacher) run.
    pub pretrained: Vec<PathFrame>,
    /// Frames of the stylized run.
    pub stylized: Vec<PathFrame>,
}

impl PathRenders {
    /// Renders `cameras` with the pair's teacher (unstylized) and student (under `code`),
    /// calling `progress(done)` after each frame.
    pub fn render(
        pair: &StylizedPair,
        cameras: Vec<Camera>,
        code: Option<Tensor<2>>,
        device: &Device,
        mut progress: impl FnMut(usize),
    ) -> Result<Self> {
        let mut pretrained = Vec::with_capacity(cameras.len());
        let mut stylized = Vec::with_capacity(cameras.len());
        for (i, cam) in cameras.iter().enumerate() {
            let (teacher, student) =
                pair.student
                    .frame_pair(pair.teacher.as_ref(), cam, code.clone(), device)?;
            pretrained.push(teacher);
            stylized.push(student);
            progress(i + 1);
        }
        Ok(Self {
            cameras,
            pretrained,
            stylized,
        })
    }

    /// The path's geometry: the pretrained model's surface points.
    pub fn geometry(&self) -> PathGeometry {
        PathGeometry {
            cameras: self.cameras.clone(),
            points: self.pretrained.iter().map(|f| f.points.clone()).collect(),
        }
    }

    /// Median relative depth error of the stylized frames against the pretrained ones on
    /// pixels on the object in both (mean over frames), and the fraction of pixels that are on
    /// the object in both or in neither.
    pub fn depth_agreement(&self) -> (f64, f64) {
        let n = self.cameras.len().max(1) as f64;
        let (mut err, mut agree) = (0.0, 0.0);
        for (s, t) in self.stylized.iter().zip(&self.pretrained) {
            let d = DepthAgreement::of(&s.depth, &t.depth);
            err += d.median_rel_error;
            agree += d.agreement;
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

/// Indices of the VGG layers (relu1_2, relu2_2) whose nearest-neighbour distance to a painting
/// mostly reads its colours: the palette.
pub const PALETTE_LAYERS: [usize; 2] = [0, 1];
/// Indices of the layers (relu3_3, relu4_3) that read its strokes: the texture.
pub const TEXTURE_LAYERS: [usize; 2] = [2, 3];

/// A painting's features as the texture measure reads them: per layer, a regular subsample of
/// its positions, as unit columns.
pub struct PaintingFeatures(pub [Tensor<2>; 4]);

impl PaintingFeatures {
    /// The features of `painting`, fitted within `size` pixels as in training.
    pub fn new(vgg: &Vgg, painting: &RgbImage, size: usize, device: &Device) -> Self {
        let f = vgg.features(painting.fit_within(size).to_tensor(device));
        Self(std::array::from_fn(|l| {
            ins_core::eval::feature_match::painting_positions(f.style_layers()[l].clone())
        }))
    }
}

/// Per VGG layer, the mean over `frames` of the nearest-neighbour feature distance to the
/// painting on the pixels `masks` marks (the object): 1 − the best cosine similarity of each
/// object position to any position of the painting.
pub fn texture_distances(
    vgg: &Vgg,
    painting: &PaintingFeatures,
    frames: &[RgbImage],
    masks: &[Vec<bool>],
    device: &Device,
) -> [f64; 4] {
    use ins_core::eval::feature_match::{mask_at_layer, nn_distance, positions};
    let mut sums = [0.0f64; 4];
    let mut counts = [0usize; 4];
    for (frame, mask) in frames.iter().zip(masks) {
        let feats = vgg.features(frame.to_tensor(device));
        for (l, f) in feats.style_layers().into_iter().enumerate() {
            let [_, _, lh, lw] = f.dims();
            let keep = mask_at_layer(mask, frame.width, frame.height, lw, lh);
            if let Some(p) = positions(f.clone(), &keep) {
                sums[l] += nn_distance(p, painting.0[l].clone());
                counts[l] += 1;
            }
        }
    }
    std::array::from_fn(|l| sums[l] / counts[l].max(1) as f64)
}
