//! Style and content losses on VGG features.

use burn::prelude::*;
use vgg_import::{Vgg, VggFeatures};

use crate::train::Probe;

use super::color_transfer::ColorTransfer;
use super::saturation::{collapse_probe, pure_share};
use super::style::{MatchGuide, StyleLoss, StyleTargets, UNGUIDED_RADIUS};

/// mean((relu2_2(x) − target)²); `target` is `[B, C, H, W]` or broadcastable.
pub fn content_loss(features: &VggFeatures, target: &Tensor<4>) -> Tensor<1> {
    (features.relu2_2.clone() - target.clone()).square().mean()
}

/// The content loss between two RGB images of the same size (relu2_2 mean squared difference).
pub fn content_distance(vgg: &Vgg, rgb: Tensor<4>, reference: Tensor<4>) -> f64 {
    let target = vgg.features(reference).relu2_2;
    content_loss(&vgg.features(rgb), &target).into_scalar::<f32>() as f64
}

/// One-hot codes of `n` styles, `[n, n]`: every stylizing step renders its patch under each.
pub fn one_hot_codes(n: usize, device: &Device) -> Tensor<2> {
    let mut v = vec![0f32; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    Tensor::from_data(TensorData::new(v, [n, n]), device)
}

/// The stylization loss every variant trains with (SIREN, NeRF, IDR, the 2D baseline and the
/// benchmarks): a frozen VGG-16, each painting's style targets, and the one-hot codes under
/// which a step renders its patch, one image per style.
///
/// A step hands [`PerceptualLoss::terms`] the rendered patches `[S, 3, K, K]` (row `i` under
/// style `i`) and the relu2_2 features of the photo at the same pixels
/// ([`PerceptualLoss::content_target`]); it gets back the `style` and `content` terms, which the
/// phase weighs.
#[derive(Clone)]
pub struct PerceptualLoss {
    /// Frozen VGG-16.
    pub vgg: Vgg,
    /// The paintings' targets (row `i`: style `i`) of the style term's kind.
    pub targets: StyleTargets,
    /// One-hot codes, `[S, S]`.
    pub codes: Tensor<2>,
    /// Per style, the colour map that recolours the photos before their content features are
    /// taken (ARF's colour transfer), where asked for.
    pub recolor: Option<Vec<ColorTransfer>>,
    /// NNFM's matches restricted to painting features within this radius (in cosine) of the
    /// photo's best match at each position, where asked for ([`StyleTargets::match_guide`]).
    pub match_radius: Option<f32>,
    /// The radius at the texture layers (relu3_3, relu4_3), where it differs from
    /// `match_radius` (which then holds at the palette layers, relu1_2 and relu2_2).
    pub texture_match_radius: Option<f32>,
    /// The largest share of pure pixels (black, white, primaries) among the paintings, as the
    /// loss sees them: how much of a render may go pure without having collapsed.
    pub painting_pure_share: f32,
}

impl PerceptualLoss {
    /// The loss of `styles`, each fitted within `style_size` pixels, matched by `kind`,
    /// through `vgg` on `device` (the device the training runs on).
    pub fn new(
        vgg: Vgg,
        styles: &[crate::imaging::RgbImage],
        style_size: usize,
        kind: StyleLoss,
        device: &Device,
    ) -> Self {
        let fitted: Vec<_> = styles.iter().map(|s| s.fit_within(style_size)).collect();
        let paintings: Vec<Tensor<4>> = fitted.iter().map(|s| s.to_tensor(device)).collect();
        let targets = StyleTargets::from_images(kind, &vgg, &paintings);
        Self {
            vgg,
            targets,
            codes: one_hot_codes(styles.len(), device),
            recolor: None,
            match_radius: None,
            texture_match_radius: None,
            painting_pure_share: fitted
                .iter()
                .map(|p| pure_share(&p.data))
                .fold(0.0, f32::max),
        }
    }

    /// The loss with NNFM's matches guided by the photo within `radius` (`None`: unguided;
    /// ignored by the other kinds).
    pub fn with_match_radius(mut self, radius: Option<f32>) -> Self {
        self.match_radius = radius;
        self
    }

    /// The loss with another radius at the texture layers (relu3_3, relu4_3) than at the
    /// palette layers (`None`: the same).
    pub fn with_texture_match_radius(mut self, radius: Option<f32>) -> Self {
        self.texture_match_radius = radius;
        self
    }

    /// NNFM's radius at each style layer (relu1_2, relu2_2, relu3_3, relu4_3); unguided is
    /// [`UNGUIDED_RADIUS`].
    pub fn match_radii(&self) -> [f32; 4] {
        let palette = self.match_radius.unwrap_or(UNGUIDED_RADIUS);
        let texture = self.texture_match_radius.unwrap_or(palette);
        [palette, palette, texture, texture]
    }

    /// The loss with the content photos recoloured into each painting's palette: `palette` is
    /// a sample of the scene's colours, `styles` the paintings (in the loss's order).
    pub fn with_color_transfer(
        mut self,
        palette: &[[f32; 3]],
        styles: &[crate::imaging::RgbImage],
    ) -> Self {
        self.recolor = Some(
            styles
                .iter()
                .map(|s| {
                    let painting: Vec<[f32; 3]> =
                        s.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
                    ColorTransfer::fit(palette, &painting)
                })
                .collect(),
        );
        self
    }

    /// Number of styles.
    pub fn n_styles(&self) -> usize {
        self.codes.dims()[0]
    }

    /// The code of the first style, `[1, S]`, on the inner (non-autodiff) device: what
    /// evaluations during training render with.
    pub fn first_code(&self) -> Tensor<2> {
        self.codes.clone().slice([0..1]).inner()
    }

    /// The content target of a photo `[1, 3, H, W]`: its relu2_2 features, detached; with
    /// colour transfer, those of the photo recoloured for each style, `[S, C, H', W']`. With a
    /// match radius, also which painting features each of its positions may match.
    pub fn content_target(&self, photo: Tensor<4>) -> ContentTarget {
        let photo = match &self.recolor {
            None => photo,
            Some(maps) => {
                let device = photo.device();
                let [_, _, h, w] = photo.dims();
                let s = maps.len();
                let a: Vec<f32> = maps.iter().flat_map(|m| m.matrix.concat()).collect();
                let b: Vec<f32> = maps.iter().flat_map(|m| m.offset).collect();
                let a = Tensor::<1>::from_floats(a.as_slice(), &device).reshape([s, 3, 3]);
                let b = Tensor::<1>::from_floats(b.as_slice(), &device).reshape([s, 3, 1]);
                let x = photo.reshape([1, 3, h * w]).expand([s, 3, h * w]);
                (a.matmul(x) + b).clamp(0.0, 1.0).reshape([s, 3, h, w])
            }
        };
        let features = self.vgg.features(photo);
        ContentTarget {
            guide: self.targets.match_guide(&features, self.match_radii()),
            relu2_2: features.relu2_2.detach(),
        }
    }

    /// The probe that watches the renders `[S, 3, K, K]` of a stylization step at `lr` for a
    /// collapse to pure colours where the photo `[1, 3, K, K]` is coloured
    /// ([`collapse_probe`], against the paintings' own pure share).
    pub fn saturation_probe(&self, renders: Tensor<4>, photo: Tensor<4>, lr: f64) -> Probe {
        collapse_probe(renders, photo, self.painting_pure_share, lr)
    }

    /// The `style` and `content` terms of rendered images `[S, 3, H, W]` against the targets
    /// and `content_target` (broadcast over the styles).
    pub fn terms(&self, images: Tensor<4>, content: &ContentTarget) -> (Tensor<1>, Tensor<1>) {
        let feats = self.vgg.features(images);
        (
            self.targets.loss(&feats, content.guide.as_ref()),
            content_loss(&feats, &content.relu2_2),
        )
    }
}

/// What a render of some pixels is compared with, taken once from the photo's same pixels.
#[derive(Clone, Debug)]
pub struct ContentTarget {
    /// The photo's relu2_2 features, detached, `[1 or S, C, H', W']`.
    pub relu2_2: Tensor<4>,
    /// For a guided NNFM, which painting features the photo's positions may match.
    pub guide: Option<MatchGuide>,
}

/// Rendered patch rows → images: `[S·K·K, 3]` (or any shape holding them in that order, style
/// by style, each row major) → `[S, 3, K, K]`, the layout VGG reads.
pub fn patch_images<const D: usize>(rgb: Tensor<D>, styles: usize, k: usize) -> Tensor<4> {
    rgb.reshape([styles, k, k, 3]).permute([0, 3, 1, 2])
}

/// A photo patch's pixels (row major, K·K of them) as an image `[1, 3, K, K]`.
pub fn photo_patch(rgb: &[[f32; 3]], k: usize, device: &Device) -> Tensor<4> {
    patch_images(Tensor::<1>::from_floats(rgb.as_flattened(), device), 1, k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::RgbImage;

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> RgbImage {
        let f = &f;
        let data = (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| f(x, y)))
            .collect();
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    /// A VGG-16 of random weights (seeded), enough where only shapes and identities matter.
    fn random_vgg(d: &Device, seed: u64) -> Vgg {
        d.seed(seed);
        Vgg {
            net: vgg_import::Vgg16Features::random(d),
            preprocess: vgg_import::Preprocess::Caffe,
        }
    }

    /// A 16² photo (a red-green ramp) and a 16² blue painting.
    fn photo_and_blue_painting() -> (RgbImage, RgbImage) {
        (
            image(16, 16, |x, y| [x as f32 / 16.0, y as f32 / 16.0, 0.5]),
            image(16, 16, |x, _| [0.1, 0.2, 0.5 + x as f32 / 40.0]),
        )
    }

    #[test]
    fn colour_transfer_recolours_the_content_per_style() {
        let d = Device::flex();
        let vgg = random_vgg(&d, 1);
        let (photo, blue) = photo_and_blue_painting();
        let plain =
            PerceptualLoss::new(vgg, &[photo.clone(), blue.clone()], 16, StyleLoss::Gram, &d);
        let target = plain.content_target(photo.to_tensor(&d)).relu2_2;
        assert_eq!(target.dims()[0], 1);
        let palette: Vec<[f32; 3]> = photo.data.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let recoloured = plain
            .clone()
            .with_color_transfer(&palette, &[photo.clone(), blue]);
        let t = recoloured.content_target(photo.to_tensor(&d)).relu2_2;
        // One target per style: the first painting is the photo itself (the map is the
        // identity), the second recolours it.
        assert_eq!(t.dims()[0], 2);
        let same = (t.clone().slice([0..1]) - target.clone())
            .abs()
            .max()
            .into_scalar::<f32>();
        let other = (t.slice([1..2]) - target).abs().max().into_scalar::<f32>();
        assert!(
            same < 1e-2 * other,
            "identity map moved the target: {same} vs {other}"
        );
    }

    #[test]
    fn a_match_radius_below_two_guides_nnfm_and_from_two_it_is_plain_nnfm() {
        let d = Device::flex();
        let vgg = random_vgg(&d, 2);
        let (photo, painting) = photo_and_blue_painting();
        let nnfm = PerceptualLoss::new(
            vgg,
            std::slice::from_ref(&painting),
            16,
            StyleLoss::Nnfm,
            &d,
        );
        let guide = |r: Option<f32>| {
            nnfm.clone()
                .with_match_radius(r)
                .content_target(photo.to_tensor(&d))
                .guide
                .is_some()
        };
        assert!(guide(Some(0.2)));
        assert!(!guide(Some(2.0)));
        assert!(!guide(None));
        // A radius per layer group: only the layers under 2 are guided.
        let layers = |palette: Option<f32>, texture: Option<f32>| {
            let g = nnfm
                .clone()
                .with_match_radius(palette)
                .with_texture_match_radius(texture)
                .content_target(photo.to_tensor(&d))
                .guide;
            g.map(|g| g[0].each_ref().map(|l| l.is_some()))
        };
        assert_eq!(layers(Some(0.2), None), Some([true; 4]));
        assert_eq!(
            layers(Some(0.2), Some(2.0)),
            Some([true, true, false, false])
        );
        assert_eq!(layers(None, Some(0.4)), Some([false, false, true, true]));
        assert_eq!(layers(Some(2.0), Some(2.0)), None);
        // Other losses have no matches to guide.
        let gram = PerceptualLoss::new(nnfm.vgg.clone(), &[painting], 16, StyleLoss::Gram, &d)
            .with_match_radius(Some(0.2));
        assert!(gram.content_target(photo.to_tensor(&d)).guide.is_none());
    }
}
