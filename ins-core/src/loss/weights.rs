//! Default loss weights per VGG preprocessing convention.
//!
//! Torch-convention features are ≈ k = 255·0.226 ≈ 57.6 times smaller than Caffe-convention
//! ones, so content MSE shrinks by k² and the squared Gram difference by k⁴. The defaults keep
//! the same balance under both conventions, so either set of weights stylizes out of the box.

use serde::{Deserialize, Serialize};
use vgg_import::Preprocess;

use super::style::StyleLoss;

/// Weights of the perceptual terms.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct LossWeights {
    /// Content (relu2_2) weight.
    pub content: f64,
    /// Style (Gram) weight.
    pub style: f64,
}

/// Feature-scale ratio between the Caffe and torch conventions.
pub const CAFFE_OVER_TORCH: f64 = 255.0 * 0.226;

impl LossWeights {
    /// The given weights where set, the defaults for `preprocess` and `kind` otherwise.
    pub fn or_defaults(
        preprocess: Preprocess,
        kind: StyleLoss,
        content: Option<f64>,
        style: Option<f64>,
    ) -> Self {
        let d = Self::default_for(preprocess, kind);
        Self {
            content: content.unwrap_or(d.content),
            style: style.unwrap_or(d.style),
        }
    }

    /// Defaults for `preprocess` and `kind`, equivalent under both conventions to the Caffe
    /// ones: content 1 and style 2 (Gram), [`NNFM_WEIGHT`] (NNFM) or [`MEAN_STD_WEIGHT`].
    pub fn default_for(preprocess: Preprocess, kind: StyleLoss) -> Self {
        let style = match kind {
            StyleLoss::Gram => 2.0,
            StyleLoss::Nnfm => NNFM_WEIGHT,
            StyleLoss::MeanStd => MEAN_STD_WEIGHT,
        };
        match preprocess {
            Preprocess::Caffe => Self {
                content: 1.0,
                style,
            },
            Preprocess::Torch => {
                let k2 = CAFFE_OVER_TORCH * CAFFE_OVER_TORCH;
                // Content and channel statistics shrink by k²; squared Gram differences by k⁴;
                // NNFM's cosines not at all.
                let style_scale = match kind {
                    StyleLoss::Gram => k2 * k2,
                    StyleLoss::Nnfm | StyleLoss::MeanStd => k2,
                };
                Self {
                    content: k2,
                    style: style * style_scale,
                }
            }
        }
    }
}

/// Caffe-convention NNFM weight against content 1. Calibrated with `stylize2d` on lego's
/// frames and *The Starry Night*: 3e4 to 3e5 left the photo's colours and no strokes, 3e6 to
/// 3e7 drew the painting's strokes on the object (docs/measurements.md).
pub const NNFM_WEIGHT: f64 = 3e6;

/// Caffe-convention mean-std weight against content 1.
pub const MEAN_STD_WEIGHT: f64 = 10.0;
