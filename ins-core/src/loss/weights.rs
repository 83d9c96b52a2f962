//! Default loss weights per VGG preprocessing convention.
//!
//! Torch-convention features are ≈ k = 255·0.226 ≈ 57.6 times smaller than Caffe-convention
//! ones, so content MSE shrinks by k² and the squared Gram difference by k⁴. The defaults keep
//! the same balance under both conventions, so either set of weights stylizes out of the box.

use serde::{Deserialize, Serialize};
use vgg_import::Preprocess;

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
    /// The given weights where set, the defaults for `preprocess` otherwise.
    pub fn or_defaults(preprocess: Preprocess, content: Option<f64>, style: Option<f64>) -> Self {
        let d = Self::default_for(preprocess);
        Self {
            content: content.unwrap_or(d.content),
            style: style.unwrap_or(d.style),
        }
    }

    /// Defaults for `preprocess`, equivalent to content 1 / style 2 under Caffe preprocessing.
    pub fn default_for(preprocess: Preprocess) -> Self {
        let caffe = Self {
            content: 1.0,
            style: 2.0,
        };
        match preprocess {
            Preprocess::Caffe => caffe,
            Preprocess::Torch => {
                let k2 = CAFFE_OVER_TORCH * CAFFE_OVER_TORCH;
                Self {
                    content: caffe.content * k2,
                    style: caffe.style * k2 * k2,
                }
            }
        }
    }
}
