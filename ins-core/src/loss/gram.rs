//! Gram matrices of feature maps, and the paper's style loss built on them: the mean squared
//! difference of a render's Gram matrices to a painting's at relu1_2, relu2_2, relu3_3 and
//! relu4_3.

use burn::backend::DispatchDevice;
use burn::prelude::*;
use vgg_import::{Vgg, VggFeatures};

use crate::kernels::dense_blocks::blocks_on;
use crate::kernels::gram::gram_flex;

/// The shortest sum over pixels a GPU takes in blocks: one 64 × 64 tile of `F Fᵀ` walking
/// 16,384 pixels is about 67 M multiply-adds on one multiprocessor, a few tenths of a
/// millisecond; the blocks cost about eight launches more (their copies, the sum over blocks),
/// on the CUDA stand-in about as much host time. relu1_2 from 128² up, relu2_2 from 256².
const LONG_SUM: usize = 16_384;

/// `[B, C, H, W] → [B, C, C]`, `G = F Fᵀ / (C·H·W)`: one op with its own backward on Flex,
/// tensor ops elsewhere: on a GPU the sum over the pixels in blocks ([`gram_in_blocks`]).
pub fn gram(features: Tensor<4>) -> Tensor<3> {
    let [b, c, h, w] = features.dims();
    let f = features.reshape([b, c, h * w]);
    let scale = 1.0 / (c * h * w) as f32;
    if matches!(f.device().inner().as_dispatch(), DispatchDevice::Flex(_)) {
        return gram_flex(f, scale);
    }
    if h * w >= LONG_SUM
        && let Some(blocks) = blocks_on(&f.device(), h * w, c, c)
    {
        return gram_in_blocks(f, blocks).mul_scalar(scale);
    }
    f.clone().matmul(f.swap_dims(1, 2)).mul_scalar(scale)
}

/// `F Fᵀ` for `f [B, C, K]`, the sum over `K` taken as `blocks` partial products at once, then
/// summed. Why: `F Fᵀ` is a product with a small output (`C × C`, 64 × 64 at relu1_2) and a long
/// sum (every pixel), which CubeCL's matmuls give to as many cubes as the output has tiles (one
/// to four at relu1_2) and walk whole in each (see `kernels::dense_blocks`): the batch of blocks
/// `[B, blocks, C, K/blocks]` multiplies the cubes. The same sums, grouped differently.
///
/// # Panics
/// Unless `blocks` divides `K`.
pub fn gram_in_blocks(f: Tensor<3>, blocks: usize) -> Tensor<3> {
    let [b, c, k] = f.dims();
    assert!(
        blocks > 0 && k.is_multiple_of(blocks),
        "{blocks} blocks of {k} pixels"
    );
    let f = f.reshape([b, c, blocks, k / blocks]).swap_dims(1, 2);
    f.clone()
        .matmul(f.swap_dims(2, 3))
        .sum_dim(1)
        .reshape([b, c, c])
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::dense_blocks::assert_all_close;
    use burn::tensor::Distribution;

    /// The Gram matrix in blocks of pixels has the plain product's value and gradient (flex,
    /// autodiff), for a batch of two and blocks of several sizes.
    #[test]
    fn the_gram_in_blocks_is_the_plain_products_value_and_gradient() {
        let d = Device::flex().autodiff();
        d.seed(3);
        let f = Tensor::<3>::random([2, 5, 1_024], Distribution::Default, &d);
        let probe = Tensor::<3>::random([2, 5, 5], Distribution::Default, &d);
        let run = |blocks: usize| {
            let f = f.clone().require_grad();
            let g = match blocks {
                1 => f.clone().matmul(f.clone().swap_dims(1, 2)),
                _ => gram_in_blocks(f.clone(), blocks),
            };
            let grads = (g.clone() * probe.clone()).sum().backward();
            let flat = |t: Tensor<3>| t.into_data().try_to_vec::<f32>().unwrap();
            [flat(g.inner()), flat(f.grad(&grads).unwrap())]
        };
        let plain = run(1);
        for blocks in [2, 16, 256] {
            assert_all_close(&plain, &run(blocks), &format!("{blocks} blocks"));
        }
    }
}
