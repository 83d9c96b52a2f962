//! Input conventions of VGG-16 weights.
//!
//! Keras / Caffe weights (the default, from tf2onnx) expect BGR in 0–255 minus the ImageNet mean
//! (103.939, 116.779, 123.68); torchvision weights expect RGB in [0, 1] normalised by the ImageNet
//! mean (0.485, 0.456, 0.406) and std (0.229, 0.224, 0.225). Features differ in scale by about
//! 255·0.226 ≈ 58 between the two, so loss weights depend on the convention.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

/// A preprocessing convention.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Hash)]
#[serde(rename_all = "lowercase")]
pub enum Preprocess {
    /// BGR, 0–255, mean-subtracted.
    Caffe,
    /// RGB, [0,1], mean/std normalised.
    Torch,
}

impl std::str::FromStr for Preprocess {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "caffe" => Ok(Self::Caffe),
            "torch" | "pytorch" => Ok(Self::Torch),
            _ => Err(format!(
                "unknown preprocessing {s:?} (expected caffe or torch)"
            )),
        }
    }
}

impl std::fmt::Display for Preprocess {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Caffe => "caffe",
            Self::Torch => "torch",
        })
    }
}

impl Preprocess {
    /// Maps an RGB batch in [0, 1], `[B, 3, H, W]`, to the network's input.
    pub fn apply(&self, rgb: Tensor<4>) -> Tensor<4> {
        let device = rgb.device();
        let (scale, mean, std, bgr) = match self {
            Self::Caffe => (255.0, [123.68, 116.779, 103.939], [1.0, 1.0, 1.0], true),
            Self::Torch => (1.0, [0.485, 0.456, 0.406], [0.229, 0.224, 0.225], false),
        };
        let x = if bgr { rgb.flip([1]) } else { rgb };
        let (mean, std) = if bgr {
            ([mean[2], mean[1], mean[0]], [std[2], std[1], std[0]])
        } else {
            (mean, std)
        };
        let mean = Tensor::<1>::from_floats(mean, &device).reshape([1, 3, 1, 1]);
        let inv_std =
            Tensor::<1>::from_floats(std.map(|s: f32| 1.0 / s), &device).reshape([1, 3, 1, 1]);
        (x.mul_scalar(scale) - mean) * inv_std
    }
}
