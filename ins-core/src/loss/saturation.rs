//! Renders that collapse to pure colours. Every variant ends in a sigmoid; a stylization run
//! at a learning rate far above its default can drive the colour logits past ±10 within a few
//! steps (white, black or a primary everywhere), where the sigmoid passes almost no gradient
//! back and the style term stops moving for good. This measures how much of a rendered patch
//! went pure where neither its photo nor the painting is, so the trainer can say so.

use burn::prelude::*;

use crate::train::{Probe, Watch};

/// A channel within this of 0 or 1 is saturated (it rounds to 0 or 255 in 8 bits).
pub const TOLERANCE: f32 = 1.0 / 255.0;

/// Whether every channel of each pixel is saturated: `[N, 3, H, W]` → `[N, 1, H, W]`, 1 or 0.
fn saturated_pixels(images: Tensor<4>) -> Tensor<4> {
    let distance = images.clone().min_pair(images.neg().add_scalar(1.0));
    distance.max_dim(1).lower_equal_elem(TOLERANCE).float()
}

/// Of the pixels the photo shows in some colour that is not pure (at least one channel away
/// from 0 and 1), the share that the renders draw pure, over every style: renders `[S, 3, K,
/// K]` and the photo's same pixels `[1, 3, K, K]` → `[1]` in [0, 1] (0 when the photo is pure
/// everywhere). Computed on the device, detached.
pub fn saturated_share(renders: Tensor<4>, photo: Tensor<4>) -> Tensor<1> {
    let renders = renders.detach();
    let styles = renders.dims()[0];
    let coloured = saturated_pixels(photo.detach()).neg().add_scalar(1.0);
    let pure = saturated_pixels(renders) * coloured.clone();
    let count = coloured.sum().mul_scalar(styles as f32).clamp_min(1.0);
    pure.sum() / count
}

/// The share of pure pixels (every channel within [`TOLERANCE`] of 0 or 1) among `rgb`, a
/// flat `[r, g, b, r, g, b, …]` list (an image's data): a painting's own.
pub fn pure_share(rgb: &[f32]) -> f32 {
    let n = rgb.len() / 3;
    if n == 0 {
        return 0.0;
    }
    let pure = rgb
        .chunks_exact(3)
        .filter(|p| p.iter().all(|&c| c.min(1.0 - c) <= TOLERANCE))
        .count();
    pure as f32 / n as f32
}

/// The [`saturated_share`] above which a render has collapsed: half its coloured pixels, or
/// halfway from the painting's own share of pure pixels to all of them (an ink drawing's
/// black and white are no collapse).
pub fn collapse_limit(painting_pure_share: f32) -> f64 {
    (0.5f64).max((1.0 + painting_pure_share as f64) / 2.0)
}

/// Steps in a row of collapsed renders that make the trainer warn: a stall, not one patch.
const COLLAPSE_STEPS: usize = 10;

/// The `saturated` probe of a stylization step at `lr`: [`saturated_share`] of the renders
/// against the photo, watched against [`collapse_limit`] of the paintings' pure share. The
/// warning names the cause and the way out; the run goes on (the user decides).
pub fn collapse_probe(
    renders: Tensor<4>,
    photo: Tensor<4>,
    painting_pure_share: f32,
    lr: f64,
) -> Probe {
    Probe {
        name: "saturated",
        value: saturated_share(renders, photo),
        watch: Some(Watch {
            limit: collapse_limit(painting_pure_share),
            steps: COLLAPSE_STEPS,
            warning: format!(
                "the renders went pure white, black or primary where the photos are coloured \
                 (the colour's sigmoid passes almost no gradient there, so the painting cannot be \
                 learned from here); the learning rate ({lr:.1e}) is likely too high: stylize \
                 again with a lower --lr, or without it for the variant's default"
            ),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(pixels: &[[f32; 3]], k: usize) -> Tensor<4> {
        let d = Device::flex();
        Tensor::<1>::from_floats(pixels.as_flattened(), &d)
            .reshape([1, k, k, 3])
            .permute([0, 3, 1, 2])
    }

    fn value(t: Tensor<1>) -> f32 {
        t.into_scalar::<f32>()
    }

    #[test]
    fn counts_pure_renders_only_where_the_photo_is_coloured() {
        // 2×2: the photo's first pixel is its white backdrop, the others coloured.
        let photo = image(
            &[[1.0; 3], [0.5, 0.4, 0.3], [0.2, 0.9, 0.1], [0.0, 0.0, 0.5]],
            2,
        );
        // The render keeps the backdrop white, draws one coloured pixel pure blue, one black
        // within the tolerance, and one nearly pure but one channel 2/255 off.
        let render = image(
            &[
                [1.0; 3],
                [0.0, 0.0, 1.0],
                [0.5 / 255.0, 0.0, 0.0],
                [1.0, 1.0, 1.0 - 2.0 / 255.0],
            ],
            2,
        );
        let share = value(saturated_share(render, photo.clone()));
        assert!((share - 2.0 / 3.0).abs() < 1e-6, "{share}");
        // Two styles: the second one coloured everywhere halves the share.
        let coloured = image(&[[0.3; 3]; 4], 2);
        let both = Tensor::cat(vec![image(&[[1.0; 3]; 4], 2), coloured], 0);
        let share = value(saturated_share(both, photo));
        assert!((share - 0.5).abs() < 1e-6, "{share}");
    }

    #[test]
    fn a_photo_pure_everywhere_gives_zero() {
        let white = image(&[[1.0; 3]; 4], 2);
        assert_eq!(value(saturated_share(white.clone(), white)), 0.0);
    }

    #[test]
    fn a_paintings_pure_pixels_raise_the_limit() {
        assert_eq!(
            pure_share(&[1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 1.0, 0.2]),
            0.5
        );
        assert_eq!(collapse_limit(0.0), 0.5);
        assert!((collapse_limit(0.6) - 0.8).abs() < 1e-6);
        assert_eq!(pure_share(&[]), 0.0);
    }
}
