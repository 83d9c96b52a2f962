//! Gram matrices of feature maps, and the paper's style loss built on them: the mean squared
//! difference of a render's Gram matrices to a painting's at relu1_2, relu2_2, relu3_3 and
//! relu4_3.

use burn::backend::DispatchDevice;
use burn::prelude::*;
use vgg_import::{Vgg, VggFeatures};

use crate::kernels::gram::gram_flex;

/// `[B, C, H, W] → [B, C, C]`, `G = F Fᵀ / (C·H·W)`: one op with its own backward on Flex,
/// tensor ops elsewhere.
pub fn gram(features: Tensor<4>) -> Tensor<3> {
    let [b, c, h, w] = features.dims();
    let f = features.reshape([b, c, h * w]);
    let scale = 1.0 / (c * h * w) as f32;
    if matches!(f.device().inner().as_dispatch(), DispatchDevice::Flex(_)) {
        return gram_flex(f, scale);
    }
    f.clone().matmul(f.swap_dims(1, 2)).mul_scalar(scale)
}

/// Gram matrices of a style image at the four style layers, each `[1, C, C]`.
#[derive(Clone, Debug)]
pub struct StyleTarget {
    /// relu1_2, relu2_2, relu3_3, relu4_3.
    pub grams: [Tensor<3>; 4],
}

impl StyleTarget {
    /// Targets of an RGB image `[1, 3, H, W]` in [0, 1].
    pub fn from_image(vgg: &Vgg, rgb: Tensor<4>) -> Self {
        Self::from_features(&vgg.features(rgb))
    }

    /// Targets from already computed features (detached).
    pub fn from_features(f: &VggFeatures) -> Self {
        let g = f.style_layers().map(|t| gram(t.clone()).detach());
        Self { grams: g }
    }

    /// The stacked targets (see [`StyleTarget::stack`]) of style images, each first fitted
    /// within `max_side` pixels: what every stylizing variant trains against.
    pub fn stacked_from_images(
        vgg: &Vgg,
        styles: &[crate::imaging::RgbImage],
        max_side: usize,
        device: &Device,
    ) -> [Tensor<3>; 4] {
        let targets: Vec<StyleTarget> = styles
            .iter()
            .map(|s| Self::from_image(vgg, s.fit_within(max_side).to_tensor(device)))
            .collect();
        Self::stack(&targets)
    }

    /// Stacks per-image targets into `[S, C, C]` per layer, one row per image of a batch.
    pub fn stack(targets: &[StyleTarget]) -> [Tensor<3>; 4] {
        std::array::from_fn(|l| {
            Tensor::cat(targets.iter().map(|t| t.grams[l].clone()).collect(), 0)
        })
    }
}

/// Σ over layers of mean((G(x) − G_target)²). `targets[l]` is `[B, C, C]` or `[1, C, C]`
/// (broadcast over the batch).
pub fn style_loss(features: &VggFeatures, targets: &[Tensor<3>; 4]) -> Tensor<1> {
    let mut total: Option<Tensor<1>> = None;
    for (l, f) in features.style_layers().into_iter().enumerate() {
        let g = gram(f.clone());
        let diff = g - targets[l].clone();
        let term = diff.square().mean();
        total = Some(match total {
            Some(t) => t + term,
            None => term,
        });
    }
    total.expect("four style layers")
}

/// Per-layer style distances (for reports): mean((G(x) − G_target)²) at each layer.
pub fn style_distances(features: &VggFeatures, targets: &[Tensor<3>; 4]) -> [f32; 4] {
    std::array::from_fn(|l| {
        let g = gram(features.style_layers()[l].clone());
        (g - targets[l].clone())
            .square()
            .mean()
            .into_scalar::<f32>()
    })
}

/// The style loss of an RGB image `[1, 3, H, W]` against Gram targets, as a number: how far an
/// image is from a painting's style, by the definition training minimises.
pub fn style_distance(vgg: &Vgg, rgb: Tensor<4>, targets: &[Tensor<3>; 4]) -> f64 {
    style_loss(&vgg.features(rgb), targets).into_scalar::<f32>() as f64
}
