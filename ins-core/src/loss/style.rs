//! The style term: how a render's VGG features are brought to a painting's.
//!
//! - [`StyleLoss::Gram`]: Gatys' Gram matrices (the paper's): the painting's second-order
//!   statistics, averaged over the whole canvas.
//! - [`StyleLoss::Nnfm`]: ARF's nearest-neighbour feature matching: every position of the render
//!   is pulled, by cosine distance, towards the painting's feature nearest to it. It copies
//!   strokes rather than averages, and the measure of `eval consistency` is its distance.
//! - [`StyleLoss::MeanStd`]: AdaIN's statistics, each channel's mean and standard deviation.
//!
//! Each is summed over the layers relu1_2, relu2_2, relu3_3, relu4_3 and averaged over the
//! styles of a batch (row `i` of the batch against painting `i`).

use burn::prelude::*;
use serde::{Deserialize, Serialize};
use vgg_import::{Vgg, VggFeatures};

use super::gram::gram;
use crate::eval::feature_match::{painting_positions, unit_columns};

/// Which statistic of the painting a stylization matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum StyleLoss {
    /// Gram matrices (Gatys; the paper).
    #[default]
    Gram,
    /// Nearest-neighbour feature matching (ARF).
    Nnfm,
    /// Per-channel mean and standard deviation (AdaIN).
    MeanStd,
}

impl std::str::FromStr for StyleLoss {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "gram" => Ok(Self::Gram),
            "nnfm" => Ok(Self::Nnfm),
            "mean-std" | "meanstd" | "adain" => Ok(Self::MeanStd),
            _ => Err(format!(
                "unknown --style-loss {s:?} (expected gram, nnfm or mean-std)"
            )),
        }
    }
}

impl std::fmt::Display for StyleLoss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Gram => "gram",
            Self::Nnfm => "nnfm",
            Self::MeanStd => "mean-std",
        })
    }
}

/// The paintings' targets for one kind of style loss, one entry per style.
#[derive(Clone, Debug)]
pub enum StyleTargets {
    /// Gram matrices per layer, `[S, C, C]`.
    Gram([Tensor<3>; 4]),
    /// Per style, per layer: the painting's features as unit columns `[C, M]` (a regular
    /// subsample of its positions, see [`painting_positions`]).
    Nnfm(Vec<[Tensor<2>; 4]>),
    /// Per layer: each channel's mean and standard deviation, `[S, C]` each.
    MeanStd([(Tensor<2>, Tensor<2>); 4]),
}

/// Each channel's mean and standard deviation over the positions of `f [B, C, H, W]`.
fn moments(f: &Tensor<4>) -> (Tensor<2>, Tensor<2>) {
    let [b, c, h, w] = f.dims();
    let x = f.clone().reshape([b, c, h * w]);
    let mean = x.clone().mean_dim(2);
    let var = (x - mean.clone()).square().mean_dim(2);
    (
        mean.reshape([b, c]),
        var.add_scalar(1e-5).sqrt().reshape([b, c]),
    )
}

impl StyleTargets {
    /// The targets of `kind` from each painting's features (one batch of one per painting).
    pub fn from_features(kind: StyleLoss, paintings: &[VggFeatures]) -> Self {
        match kind {
            StyleLoss::Gram => StyleTargets::Gram(std::array::from_fn(|l| {
                Tensor::cat(
                    paintings
                        .iter()
                        .map(|p| gram(p.style_layers()[l].clone()).detach())
                        .collect(),
                    0,
                )
            })),
            StyleLoss::Nnfm => StyleTargets::Nnfm(
                paintings
                    .iter()
                    .map(|p| {
                        std::array::from_fn(|l| {
                            unit_columns(painting_positions(p.style_layers()[l].clone().detach()))
                        })
                    })
                    .collect(),
            ),
            StyleLoss::MeanStd => StyleTargets::MeanStd(std::array::from_fn(|l| {
                let m: Vec<(Tensor<2>, Tensor<2>)> = paintings
                    .iter()
                    .map(|p| moments(&p.style_layers()[l].clone().detach()))
                    .collect();
                (
                    Tensor::cat(m.iter().map(|(a, _)| a.clone()).collect(), 0),
                    Tensor::cat(m.iter().map(|(_, s)| s.clone()).collect(), 0),
                )
            })),
        }
    }

    /// The targets of `kind` for `paintings` (`[1, 3, H, W]` each) through `vgg`.
    pub fn from_images(kind: StyleLoss, vgg: &Vgg, paintings: &[Tensor<4>]) -> Self {
        let feats: Vec<VggFeatures> = paintings.iter().map(|p| vgg.features(p.clone())).collect();
        Self::from_features(kind, &feats)
    }

    /// Which kind these targets are for.
    pub fn kind(&self) -> StyleLoss {
        match self {
            StyleTargets::Gram(_) => StyleLoss::Gram,
            StyleTargets::Nnfm(_) => StyleLoss::Nnfm,
            StyleTargets::MeanStd(_) => StyleLoss::MeanStd,
        }
    }

    /// The style term of `features` (batch row `i` against painting `i`; a batch of one
    /// against every painting is not meant).
    pub fn loss(&self, features: &VggFeatures) -> Tensor<1> {
        match self {
            StyleTargets::Gram(grams) => super::perceptual::style_loss(features, grams),
            StyleTargets::Nnfm(paintings) => {
                let layers = features.style_layers();
                let mut total: Option<Tensor<1>> = None;
                for (l, f) in layers.iter().enumerate() {
                    for (i, painting) in paintings.iter().enumerate() {
                        let [_, c, h, w] = f.dims();
                        let fi = (*f).clone().slice([i..i + 1]).reshape([c, h * w]);
                        let term = nnfm(fi, painting[l].clone()).div_scalar(paintings.len() as f32);
                        total = Some(match total {
                            Some(t) => t + term,
                            None => term,
                        });
                    }
                }
                total.expect("four layers and a painting")
            }
            StyleTargets::MeanStd(targets) => {
                let mut total: Option<Tensor<1>> = None;
                for (f, (mt, st)) in features.style_layers().into_iter().zip(targets) {
                    let (m, s) = moments(f);
                    let term = (m - mt.clone()).square().mean() + (s - st.clone()).square().mean();
                    total = Some(match total {
                        Some(t) => t + term,
                        None => term,
                    });
                }
                total.expect("four layers")
            }
        }
    }
}

/// ARF's NNFM term of one image's features `[C, N]` against a painting's unit columns
/// `[C, M]`: the mean over positions of 1 − cos(f_i, s_nn(i)), the nearest painting feature
/// `nn(i)` (by cosine) chosen without gradient.
pub fn nnfm(features: Tensor<2>, painting: Tensor<2>) -> Tensor<1> {
    let [c, n] = features.dims();
    let f = unit_columns(features);
    let nearest = f
        .clone()
        .detach()
        .transpose()
        .matmul(painting.clone())
        .argmax(1)
        .reshape([n]);
    let matched = painting.select(1, nearest);
    let cos = (f * matched).sum_dim(0).reshape([n]);
    let _ = c;
    cos.neg().add_scalar(1.0).mean()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t2(rows: &[&[f32]], device: &Device) -> Tensor<2> {
        let (r, c) = (rows.len(), rows[0].len());
        let data: Vec<f32> = rows.iter().flat_map(|row| row.iter().copied()).collect();
        Tensor::from_data(TensorData::new(data, [r, c]), device)
    }

    /// NNFM by brute force on the host: each column's best cosine, 1 − it, averaged.
    fn brute_force(f: &[[f32; 3]], s: &[[f32; 3]]) -> f32 {
        let cos = |a: &[f32; 3], b: &[f32; 3]| {
            let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            let na = a.iter().map(|x| x * x).sum::<f32>().sqrt();
            let nb = b.iter().map(|x| x * x).sum::<f32>().sqrt();
            dot / (na * nb)
        };
        f.iter()
            .map(|a| 1.0 - s.iter().map(|b| cos(a, b)).fold(f32::MIN, f32::max))
            .sum::<f32>()
            / f.len() as f32
    }

    #[test]
    fn nnfm_matches_a_brute_force_nearest_neighbour_search() {
        let d = Device::flex();
        let f = [
            [1.0, 0.2, 0.0],
            [0.1, 1.0, 0.3],
            [0.5, 0.5, 0.5],
            [0.0, 0.1, 2.0],
        ];
        let s = [[0.9, 0.1, 0.1], [0.0, 0.0, 1.0], [0.2, 1.0, 0.0]];
        let cols = |v: &[[f32; 3]]| {
            let rows: Vec<Vec<f32>> = (0..3).map(|c| v.iter().map(|x| x[c]).collect()).collect();
            let refs: Vec<&[f32]> = rows.iter().map(|r| r.as_slice()).collect();
            t2(&refs, &d)
        };
        let got = nnfm(cols(&f), unit_columns(cols(&s))).into_scalar::<f32>();
        let want = brute_force(&f, &s);
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
    }

    #[test]
    fn nnfm_pulls_each_feature_towards_its_nearest_painting_feature() {
        let d = Device::flex().autodiff();
        // One feature (1, 0.5); painting features (1, 0) (nearest) and (0, 1).
        let f = t2(&[&[1.0], &[0.5]], &d).require_grad();
        let s = unit_columns(t2(&[&[1.0, 0.0], &[0.0, 1.0]], &d));
        let grads = nnfm(f.clone(), s).backward();
        let g = f
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        // Descending the gradient turns the feature towards (1, 0): its second component falls.
        assert!(g[1] > 0.0 && g[0] < 0.0, "{g:?}");
    }

    #[test]
    fn each_loss_is_zero_on_the_painting_itself_and_positive_elsewhere() {
        let d = Device::flex();
        d.seed(3);
        let vgg = Vgg {
            net: vgg_import::Vgg16Features::random(&d),
            preprocess: vgg_import::Preprocess::Caffe,
        };
        let painting = Tensor::<4>::random([1, 3, 32, 32], burn::tensor::Distribution::Default, &d);
        let other = Tensor::<4>::random([1, 3, 32, 32], burn::tensor::Distribution::Default, &d);
        for kind in [StyleLoss::Gram, StyleLoss::Nnfm, StyleLoss::MeanStd] {
            let t = StyleTargets::from_images(kind, &vgg, std::slice::from_ref(&painting));
            assert_eq!(t.kind(), kind);
            let same = t.loss(&vgg.features(painting.clone())).into_scalar::<f32>();
            let diff = t.loss(&vgg.features(other.clone())).into_scalar::<f32>();
            assert!(
                same.abs() < 1e-4 * diff.abs().max(1e-6),
                "{kind}: {same} vs {diff}"
            );
            assert!(diff > 0.0, "{kind}");
        }
    }
}
