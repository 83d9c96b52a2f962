//! Finding the training photos of a capture whose poses are wrong, partway through
//! pretraining, so the rest train without them.
//!
//! Why: structure from motion sometimes registers a photo in a wrong but self-consistent
//! pose (a mirror-image placement across the object, a sub-model glued on badly). Its rays
//! then teach the field a second, contradictory object that every other view looks through.
//! `data sfm` on the phone-like lego capture registered 44 photos, 6 of them turned ~180° and
//! across the object: pretraining on all 44 reached 20.6 dB on held-out views, without those 6
//! 27.0. Once the field has taken shape from the majority, such a photo stands out: its
//! pixels fit far worse than the others' (11.7–15.8 dB against a median of 24.5 there).
//!
//! Only captures (COLMAP, transforms.json) are audited: datasets ship poses checked by their
//! authors, and a capture's photos differ in how well they fit by a few dB at most when their
//! poses are right.

use anyhow::Result;
use burn::prelude::*;
use ins_scene::data::{Scene, SceneFormat};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::eval::render_rays;
use super::model::NerfModel;
use super::render::{RenderRays, Sampling};

/// Share of the pretraining steps after which the photos are audited: the field has taken
/// shape from the majority, and the rest of pretraining repairs what the outliers taught it.
pub const AUDIT_AT: f64 = 0.3;
/// Random pixels rendered per photo: enough to place its PSNR within a few tenths of a dB.
pub const AUDIT_PIXELS: usize = 1024;
/// How far below the photos' median PSNR a photo must fit to count as wrongly posed: well past
/// the spread of correctly posed photos (a few dB between views seen more or less often).
pub const OUTLIER_DB: f64 = 6.0;
/// Most photos the audit drops: when more fit that badly, the capture has a problem the
/// poses of a few photos do not explain (the field itself has not converged), and none is
/// dropped.
pub const MAX_OUTLIER_SHARE: f64 = 0.2;

/// Whether a scene's photos are audited.
pub fn audits_views(scene: &Scene) -> bool {
    matches!(scene.format, SceneFormat::Colmap | SceneFormat::Transforms)
}

/// How well one photo fits the field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewFit {
    /// View index in the scene.
    pub view: usize,
    /// PSNR of [`AUDIT_PIXELS`] random pixels, in dB.
    pub psnr: f64,
}

/// Renders [`AUDIT_PIXELS`] random pixels of each of `views` (seeded) and scores them.
pub fn fit_views(
    model: &NerfModel,
    scene: &Scene,
    views: &[usize],
    sampling: Sampling,
    background: [f32; 3],
    seed: u64,
    device: &Device,
) -> Result<Vec<ViewFit>> {
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut fits = Vec::with_capacity(views.len());
    for &view in views {
        let image = &scene.views[view].image;
        let pixels: Vec<(u32, u32)> = (0..AUDIT_PIXELS)
            .map(|_| {
                (
                    rng.random_range(0..image.width),
                    rng.random_range(0..image.height),
                )
            })
            .collect();
        let rays = RenderRays::for_scene(scene, scene.pixel_rays(view, &pixels)?);
        let out = render_rays(
            model,
            &rays,
            pixels.len(),
            1,
            sampling,
            None,
            background,
            device,
        )?;
        let mse = pixels
            .iter()
            .zip(out.rgb.chunks_exact(3))
            .map(|(&(x, y), got)| {
                let want = image.rgb(x, y);
                (0..3).map(|c| (got[c] - want[c]).powi(2)).sum::<f32>() as f64 / 3.0
            })
            .sum::<f64>()
            / pixels.len() as f64;
        fits.push(ViewFit {
            view,
            psnr: -10.0 * mse.max(1e-10).log10(),
        });
    }
    Ok(fits)
}

/// The views that fit more than [`OUTLIER_DB`] below the median, worst first; none when more
/// than [`MAX_OUTLIER_SHARE`] of them do, or fewer than 5 photos are audited.
pub fn outliers(fits: &[ViewFit]) -> Vec<ViewFit> {
    if fits.len() < 5 {
        return Vec::new();
    }
    let median = median_psnr(fits);
    let mut out: Vec<ViewFit> = fits
        .iter()
        .filter(|f| f.psnr < median - OUTLIER_DB)
        .copied()
        .collect();
    if out.len() as f64 > MAX_OUTLIER_SHARE * fits.len() as f64 {
        return Vec::new();
    }
    out.sort_by(|a, b| a.psnr.total_cmp(&b.psnr));
    out
}

/// A photo's file name (for messages naming it).
pub fn photo_name(scene: &Scene, view: usize) -> String {
    let path = &scene.views[view].path;
    path.file_name()
        .unwrap_or(path.as_os_str())
        .to_string_lossy()
        .into_owned()
}

/// The median PSNR of `fits`.
pub fn median_psnr(fits: &[ViewFit]) -> f64 {
    let mut sorted: Vec<f64> = fits.iter().map(|f| f.psnr).collect();
    sorted.sort_by(f64::total_cmp);
    sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fits(psnr: &[f64]) -> Vec<ViewFit> {
        psnr.iter()
            .enumerate()
            .map(|(view, &psnr)| ViewFit { view, psnr })
            .collect()
    }

    #[test]
    fn photos_far_below_the_rest_are_outliers_worst_first() {
        // The phone-like capture through SfM: six photos posed across the object.
        let mut psnr = vec![24.0, 25.5, 23.2, 26.4, 24.8, 25.1, 22.9, 24.4, 25.9, 23.6];
        psnr.extend([18.9, 21.1]);
        psnr.extend(vec![24.5; 20]);
        psnr.extend([11.7, 15.8, 13.8, 15.0]);
        let out = outliers(&fits(&psnr));
        let views: Vec<usize> = out.iter().map(|f| f.view).collect();
        assert_eq!(views, [32, 34, 35, 33]);
        // Photos a few dB apart, as correctly posed ones are: none.
        assert!(outliers(&fits(&[24.0, 21.0, 26.0, 19.5, 25.0, 23.0])).is_empty());
    }

    #[test]
    fn nothing_is_dropped_when_many_photos_fit_badly_or_few_are_audited() {
        // A third of the photos far below: the field, not their poses.
        let psnr = [25.0, 25.0, 25.0, 25.0, 12.0, 12.0, 25.0, 25.0, 12.0];
        assert!(outliers(&fits(&psnr)).is_empty());
        assert!(outliers(&fits(&[25.0, 25.0, 10.0, 25.0])).is_empty());
    }
}
