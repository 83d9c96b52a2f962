//! The painting's texture on the object, per set of frames: nearest-neighbour feature distances
//! to the painting per VGG layer at a few views, and the transfer ratios they give against
//! Gatys' method run to convergence on the same views.

use burn::prelude::*;
use ins_core::eval::feature_match::transfer_ratio;
use ins_core::imaging::RgbImage;
use ins_core::train::plot::StrengthPoint;
use serde_json::json;
use vgg_import::Vgg;

use super::{
    PALETTE_LAYERS, PaintingFeatures, PathRenders, SetScores, TEXTURE_LAYERS, texture_distances,
};

/// Per set of frames, the nearest-neighbour distance to the painting on the object at each
/// style layer.
pub struct TextureTable {
    /// `(set, per-layer distance)`, the converged reference last.
    rows: Vec<(&'static str, [f64; 4])>,
}

/// The frames a [`TextureTable`] scores, all at the same reference views.
pub struct TextureSets<'a> {
    /// The stylized run's frames (the whole path).
    pub stylized: &'a [RgbImage],
    /// The per-view 2D baseline's frames (the whole path), if run.
    pub baseline: Option<&'a [RgbImage]>,
    /// Gatys run to convergence, one per reference view.
    pub converged: &'a [RgbImage],
}

impl TextureTable {
    /// Scores the pretrained frames, `sets` and the converged reference at `views` (indices
    /// into the path), on the pixels the pretrained run sees the object.
    pub fn score(
        vgg: &Vgg,
        painting: &PaintingFeatures,
        renders: &PathRenders,
        views: &[usize],
        sets: TextureSets,
        device: &Device,
    ) -> Self {
        let masks: Vec<Vec<bool>> = views
            .iter()
            .map(|&i| renders.pretrained[i].object())
            .collect();
        let pick = |frames: &[RgbImage]| -> Vec<RgbImage> {
            views.iter().map(|&i| frames[i].clone()).collect()
        };
        let pretrained: Vec<RgbImage> = views
            .iter()
            .map(|&i| renders.pretrained[i].image.clone())
            .collect();
        let d = |frames: &[RgbImage]| texture_distances(vgg, painting, frames, &masks, device);
        let mut rows = vec![
            ("pretrained", d(&pretrained)),
            ("stylized", d(&pick(sets.stylized))),
        ];
        if let Some(b) = sets.baseline {
            rows.push(("baseline2d", d(&pick(b))));
        }
        rows.push(("reference2d", d(sets.converged)));
        Self { rows }
    }

    fn distances(&self, set: &str) -> Option<[f64; 4]> {
        self.rows.iter().find(|(s, _)| *s == set).map(|(_, d)| *d)
    }

    /// Per layer, the share of the way from the pretrained frames to the converged reference
    /// that `set` went.
    pub fn ratios(&self, set: &str) -> Option<[Option<f64>; 4]> {
        let (p, r, s) = (
            self.distances("pretrained")?,
            self.distances("reference2d")?,
            self.distances(set)?,
        );
        Some(std::array::from_fn(|l| transfer_ratio(p[l], s[l], r[l])))
    }

    /// The sets that have both a texture transfer and warp errors, for the picture (the
    /// pretrained frames at 0 by definition).
    pub fn strength_points(&self, sets: &[SetScores]) -> Vec<StrengthPoint> {
        sets.iter()
            .filter_map(|s| {
                let r = self.ratios(&s.set)?;
                let texture = if s.set == "pretrained" {
                    0.0
                } else {
                    TEXTURE_LAYERS.iter().filter_map(|&l| r[l]).sum::<f64>()
                        / TEXTURE_LAYERS.len() as f64
                };
                Some(StrengthPoint {
                    set: s.set.clone(),
                    texture,
                    rmse: [s.rmse[0], s.rmse[1]],
                })
            })
            .collect()
    }

    /// The table as the summary's `texture` object.
    pub fn to_json(&self) -> serde_json::Value {
        let names = vgg_import::VggFeatures::NAMES;
        let mean = |v: [Option<f64>; 4], layers: [usize; 2]| -> Option<f64> {
            let x: Vec<f64> = layers.iter().filter_map(|&l| v[l]).collect();
            (x.len() == layers.len()).then(|| x.iter().sum::<f64>() / x.len() as f64)
        };
        let sets: Vec<serde_json::Value> = self
            .rows
            .iter()
            .map(|(set, d)| {
                let mut line = json!({"set": set});
                for (l, name) in names.iter().enumerate() {
                    line[format!("nn_{name}")] = round(d[l], 4).into();
                }
                if let Some(r) = self.ratios(set) {
                    for (l, name) in names.iter().enumerate() {
                        line[format!("transfer_{name}")] = r[l].map(|v| round(v, 3)).into();
                    }
                    line["palette_transfer"] = mean(r, PALETTE_LAYERS).map(|v| round(v, 3)).into();
                    line["texture_transfer"] = mean(r, TEXTURE_LAYERS).map(|v| round(v, 3)).into();
                }
                line
            })
            .collect();
        json!({
            "measure": "mean over object positions of 1 - best cosine similarity to the painting's VGG features",
            "sets": sets,
        })
    }
}

/// `x` rounded to `digits` decimals, for the summary's numbers.
pub fn round(x: f64, digits: i32) -> f64 {
    let f = 10f64.powi(digits);
    (x * f).round() / f
}
