//! The style term: how a render's VGG features are brought to a painting's.
//!
//! - [`StyleLoss::Gram`]: Gatys' Gram matrices (the paper's): the painting's second-order
//!   statistics, averaged over the whole canvas.
//! - [`StyleLoss::Nnfm`]: ARF's nearest-neighbour feature matching: every position of the render
//!   is pulled, by cosine distance, towards the painting's feature nearest to it. It copies
//!   strokes rather than averages, and the measure of `eval consistency` is its distance.
//! - [`StyleLoss::MeanStd`]: AdaIN's statistics, each channel's mean and standard deviation.
//!
//! NNFM can be guided by the photo ([`StyleTargets::match_guide`]): each position may then only
//! match painting features within a radius (in cosine) of the best match of the *photo's*
//! feature there. Unguided, NNFM chooses from the render alone, so once a render starts to look
//! like strokes its matches pull it further: on real photos the objects are painted over or
//! nothing happens (docs/measurements.md). Radius 0 is a style swap (Chen and Schmidt's: each
//! place takes the painting's feature nearest the photo's), 2 is plain NNFM; between, a place
//! takes strokes that resemble what the photo has there.
//!
//! Each is summed over the layers relu1_2, relu2_2, relu3_3, relu4_3 and averaged over the
//! styles of a batch (row `i` of the batch against painting `i`).

use burn::prelude::*;
use serde::{Deserialize, Serialize};
use vgg_import::{Vgg, VggFeatures};

use super::gram::gram;
use super::guided_match::{Columns, guided_nearest};
use crate::eval::feature_match::{painting_positions, unit_columns};
use crate::kernels::flex::on_flex;

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

/// Per style, per layer: what a guided NNFM's matches are held to, the photo's features there.
/// `None` at a layer left unguided (plain NNFM there).
pub type MatchGuide = Vec<[Option<PhotoGuide>; 4]>;

/// A photo's features at one layer and the radius of the guide (see [`candidates`]).
#[derive(Clone, Debug)]
pub struct PhotoGuide {
    /// The photo's features as unit columns `[C, N]`, detached.
    pub unit: Tensor<2>,
    /// How far (in cosine) below the photo's best match a render's match may lie.
    pub radius: f32,
}

/// From this radius on every feature is allowed (cosines lie in [−1, 1]): plain NNFM, without
/// the guide's cost.
pub const UNGUIDED_RADIUS: f32 = 2.0;

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

    /// For NNFM, the guide of a photo's features (a batch of one, or one row per style): at
    /// each position of layer `l`, the painting features within `radii[l]` (in cosine) of the
    /// photo's best match there (none at a layer whose radius reaches [`UNGUIDED_RADIUS`]).
    /// `None` for the other kinds, or when no layer is guided.
    pub fn match_guide(&self, photo: &VggFeatures, radii: [f32; 4]) -> Option<MatchGuide> {
        let StyleTargets::Nnfm(paintings) = self else {
            return None;
        };
        if radii.iter().all(|&r| r >= UNGUIDED_RADIUS) {
            return None;
        }
        let layers = photo.style_layers();
        Some(
            (0..paintings.len())
                .map(|i| {
                    std::array::from_fn(|l| {
                        (radii[l] < UNGUIDED_RADIUS).then(|| {
                            let f = layers[l];
                            let [b, _, _, _] = f.dims();
                            let fi = batch_row(f.clone().detach(), i.min(b - 1));
                            PhotoGuide {
                                unit: unit_columns(fi),
                                radius: radii[l],
                            }
                        })
                    })
                })
                .collect(),
        )
    }

    /// The style term of `features` (batch row `i` against painting `i`; a batch of one
    /// against every painting is not meant). `guide`, the photo's [`Self::match_guide`],
    /// restricts NNFM's matches; the other kinds ignore it.
    pub fn loss(&self, features: &VggFeatures, guide: Option<&MatchGuide>) -> Tensor<1> {
        match self {
            StyleTargets::Gram(grams) => super::gram::style_loss(features, grams),
            StyleTargets::Nnfm(paintings) => {
                let layers = features.style_layers();
                let mut total: Option<Tensor<1>> = None;
                for (l, f) in layers.iter().enumerate() {
                    for (i, painting) in paintings.iter().enumerate() {
                        let fi = batch_row((*f).clone(), i);
                        let photo = guide.and_then(|g| g[i][l].as_ref());
                        let term = nnfm_among(fi, painting[l].clone(), photo)
                            .div_scalar(paintings.len() as f32);
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

/// Row `i` of a batch of feature maps `[B, C, H, W]` as `[C, H·W]`; a batch of one is taken
/// whole, not sliced (a slice is a copy forward and a zeroed copy backward on the GPU).
fn batch_row(features: Tensor<4>, i: usize) -> Tensor<2> {
    let [b, c, h, w] = features.dims();
    let row = if b == 1 && i == 0 {
        features
    } else {
        features.slice([i..i + 1])
    };
    row.reshape([c, h * w])
}

/// For each column of `features [C, N]`, the column of `painting [C, M]` (unit columns) with
/// the largest cosine to it, `[C, N]`; no gradient.
pub fn nearest_columns(features: Tensor<2>, painting: Tensor<2>) -> Tensor<2> {
    nearest(features, painting, None)
}

/// The nearest painting column to each feature, among those `bias` (if any) leaves.
fn nearest(features: Tensor<2>, painting: Tensor<2>, bias: Option<Tensor<2>>) -> Tensor<2> {
    nearest_unit(unit_columns(features.detach()), painting, bias)
}

/// [`nearest`] of features already scaled to unit columns.
fn nearest_unit(unit: Tensor<2>, painting: Tensor<2>, bias: Option<Tensor<2>>) -> Tensor<2> {
    let [_, n] = unit.dims();
    let sim = unit.detach().transpose().matmul(painting.clone());
    let sim = match bias {
        Some(b) => sim + b,
        None => sim,
    };
    painting.select(1, sim.argmax(1).reshape([n])).detach()
}

/// `[N, M]`: 0 where painting column `j` is within `radius` (in cosine) of the best match of
/// photo column `i`, −4 elsewhere (so that adding it to cosines excludes those).
pub fn candidates(photo: Tensor<2>, painting: Tensor<2>, radius: f32) -> Tensor<2> {
    candidates_of_unit(unit_columns(photo.detach()), painting, radius)
}

/// [`candidates`] of a photo's unit columns.
fn candidates_of_unit(unit: Tensor<2>, painting: Tensor<2>, radius: f32) -> Tensor<2> {
    let sim = unit.transpose().matmul(painting);
    let best = sim.clone().max_dim(1);
    let [n, m] = sim.dims();
    (sim - best.expand([n, m]))
        .add_scalar(radius)
        .greater_equal_elem(0.0)
        .float()
        .mul_scalar(4.0)
        .sub_scalar(4.0)
        .detach()
}

/// For each column of `features [C, N]`, the painting column (unit, `[C, M]`) with the largest
/// cosine to it among the candidates `bias [N, M]` leaves (see [`candidates`]), `[C, N]`.
pub fn nearest_columns_among(
    features: Tensor<2>,
    painting: Tensor<2>,
    bias: Tensor<2>,
) -> Tensor<2> {
    nearest(features, painting, Some(bias))
}

/// ARF's NNFM term of one image's features `[C, N]` against a painting's unit columns
/// `[C, M]`: the mean over positions of 1 − cos(f_i, s_nn(i)), the nearest painting feature
/// `nn(i)` (by cosine) chosen without gradient.
pub fn nnfm(features: Tensor<2>, painting: Tensor<2>) -> Tensor<1> {
    nnfm_among(features, painting, None)
}

/// [`nnfm`] with the matches held to the `photo`'s guide where given (see [`candidates`]); the
/// features are scaled to unit columns once, for the match and the distance both. On the CPU
/// the match runs block by block ([`guided_nearest`]); elsewhere as tensor ops.
fn nnfm_among(features: Tensor<2>, painting: Tensor<2>, photo: Option<&PhotoGuide>) -> Tensor<1> {
    let [_, n] = features.dims();
    let unit = unit_columns(features);
    let matched = if on_flex(&unit) {
        nearest_on_host(unit.clone(), painting, photo)
    } else {
        let bias = photo.map(|g| candidates_of_unit(g.unit.clone(), painting.clone(), g.radius));
        nearest_unit(unit.clone(), painting, bias)
    };
    let cos = (unit * matched).sum_dim(0).reshape([n]);
    cos.neg().add_scalar(1.0).mean()
}

/// [`nearest_unit`] under the `photo`'s guide, by [`guided_nearest`].
fn nearest_on_host(unit: Tensor<2>, painting: Tensor<2>, photo: Option<&PhotoGuide>) -> Tensor<2> {
    let host = |t: &Tensor<2>| {
        t.clone()
            .detach()
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32 values")
    };
    let ([c, n], [_, m]) = (unit.dims(), painting.dims());
    let (r, s) = (host(&unit), host(&painting));
    let p = photo.map(|g| (host(&g.unit), g.radius));
    let index = guided_nearest(
        Columns::new(&r, c, n),
        p.as_ref()
            .map(|(p, radius)| (Columns::new(p, c, n), *radius)),
        Columns::new(&s, c, m),
        crate::kernels::dense_bf16::allowed(),
    );
    let index: Vec<i64> = index.into_iter().map(i64::from).collect();
    let index = Tensor::<1, Int>::from_data(TensorData::new(index, [n]), &unit.device());
    painting.select(1, index).detach()
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
        f.iter()
            .map(|a| 1.0 - s.iter().map(|b| cos3(a, b)).fold(f32::MIN, f32::max))
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
        let got = nnfm(columns(&f, &d), unit_columns(columns(&s, &d))).into_scalar::<f32>();
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

    /// Columns of a `[C, N]` tensor from points given as rows.
    fn columns(v: &[[f32; 3]], d: &Device) -> Tensor<2> {
        let rows: Vec<Vec<f32>> = (0..3).map(|c| v.iter().map(|x| x[c]).collect()).collect();
        let refs: Vec<&[f32]> = rows.iter().map(|r| r.as_slice()).collect();
        t2(&refs, d)
    }

    fn cos3(a: &[f32; 3], b: &[f32; 3]) -> f32 {
        let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
        dot / (a.iter().map(|x| x * x).sum::<f32>().sqrt()
            * b.iter().map(|x| x * x).sum::<f32>().sqrt())
    }

    #[test]
    fn a_guided_match_is_the_renders_nearest_among_the_photos_near_matches() {
        let d = Device::flex();
        let photo = [
            [0.9, 0.0, 0.2],
            [0.1, 0.1, 1.0],
            [0.0, 1.0, 0.1],
            [0.4, 0.5, 0.0],
        ];
        let render = [
            [0.0, 0.3, 1.0],
            [1.0, 0.0, 0.1],
            [1.0, 0.2, 0.0],
            [0.0, 0.1, 1.0],
        ];
        let s = [
            [1.0, 0.1, 0.0],
            [0.0, 0.2, 3.0],
            [0.1, 2.0, 0.0],
            [0.6, 0.6, 0.1],
        ];
        let painting = unit_columns(columns(&s, &d));
        let unit = painting.clone().into_data().try_to_vec::<f32>().unwrap();
        for radius in [0.0, 0.1, 0.3, 2.0] {
            let guide = candidates(columns(&photo, &d), painting.clone(), radius);
            let got = nearest_columns_among(columns(&render, &d), painting.clone(), guide)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            for (i, (p, r)) in photo.iter().zip(&render).enumerate() {
                // Brute force: the painting features within `radius` of the photo's best
                // cosine, and among them the one nearest the render's feature.
                let best = s.iter().map(|x| cos3(p, x)).fold(f32::MIN, f32::max);
                let want = (0..s.len())
                    .filter(|&j| cos3(p, &s[j]) >= best - radius)
                    .max_by(|&a, &b| cos3(r, &s[a]).total_cmp(&cos3(r, &s[b])))
                    .unwrap();
                for c in 0..3 {
                    let (g, w) = (got[c * photo.len() + i], unit[c * s.len() + want]);
                    assert!(
                        (g - w).abs() < 1e-6,
                        "radius {radius}, position {i}: {g} vs {w}"
                    );
                }
            }
        }
        // Radius 2 allows every painting feature: plain NNFM.
        let all = candidates(columns(&photo, &d), painting.clone(), 2.0);
        let guided = nearest_columns_among(columns(&render, &d), painting.clone(), all);
        let plain = nearest_columns(columns(&render, &d), painting);
        let diff = (guided - plain).abs().max().into_scalar::<f32>();
        assert!(diff < 1e-7, "{diff}");
    }

    #[test]
    fn guided_by_the_photo_nnfm_no_longer_follows_the_render() {
        let d = Device::flex().autodiff();
        let s = unit_columns(t2(&[&[1.0, 0.0], &[0.0, 1.0]], &d));
        // The render's feature (1, 0.5) lies nearest (1, 0); the photo's (0.2, 1) nearest (0, 1).
        let photo = t2(&[&[0.2], &[1.0]], &d);
        let grad = |loss: Tensor<1>, f: &Tensor<2>| {
            f.grad(&loss.backward())
                .unwrap()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        let f = t2(&[&[1.0], &[0.5]], &d).require_grad();
        let guide = PhotoGuide {
            unit: unit_columns(photo),
            radius: 0.1,
        };
        let g_guided = grad(nnfm_among(f.clone(), s.clone(), Some(&guide)), &f);
        let f = t2(&[&[1.0], &[0.5]], &d).require_grad();
        let g_nnfm = grad(nnfm(f.clone(), s), &f);
        // Descending: guided, the feature turns towards (0, 1); unguided, towards (1, 0).
        assert!(g_guided[0] > 0.0 && g_guided[1] < 0.0, "{g_guided:?}");
        assert!(g_nnfm[0] < 0.0 && g_nnfm[1] > 0.0, "{g_nnfm:?}");
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
        // NNFM also guided by a photo that is the painting (each position's match is itself).
        for (kind, radius) in [
            (StyleLoss::Gram, None),
            (StyleLoss::Nnfm, None),
            (StyleLoss::Nnfm, Some(0.1)),
            (StyleLoss::MeanStd, None),
        ] {
            let t = StyleTargets::from_images(kind, &vgg, std::slice::from_ref(&painting));
            assert_eq!(t.kind(), kind);
            let guide = radius.and_then(|r| t.match_guide(&vgg.features(painting.clone()), [r; 4]));
            assert_eq!(guide.is_some(), radius.is_some());
            let same = t
                .loss(&vgg.features(painting.clone()), guide.as_ref())
                .into_scalar::<f32>();
            let diff = t
                .loss(&vgg.features(other.clone()), guide.as_ref())
                .into_scalar::<f32>();
            assert!(
                same.abs() < 1e-4 * diff.abs().max(1e-6),
                "{kind}: {same} vs {diff}"
            );
            assert!(diff > 0.0, "{kind}");
        }
    }
}
