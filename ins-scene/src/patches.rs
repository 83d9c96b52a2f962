//! Strided K×K ray patches: K×K rays spread over a (K·s)×(K·s) pixel window, so a VGG loss on
//! the rendered K×K patch sees a large receptive field at the cost of K² rays (INS, Sec. 3.3).
//!
//! [`PatchSpec`] is the one definition of the window, used for images (SIREN) and for scenes
//! (NeRF, IDR): sample `(i, j)` of a patch whose window starts at `(x0, y0)` is pixel
//! `(x0 + i·s, y0 + j·s)`, and the window `[x0, x0 + K·s) × [y0, y0 + K·s)` lies inside the
//! image.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::rays::{PixelRef, RayBatch};
use crate::data::{DataError, Scene, Split};

/// Patch geometry: K rays per side, s pixels apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PatchSpec {
    /// Rays per side (K).
    pub size: u32,
    /// Pixels between neighbouring rays (s).
    pub stride: u32,
}

impl PatchSpec {
    /// K rays per side, s apart.
    pub fn new(size: u32, stride: u32) -> Self {
        Self { size, stride }
    }

    /// The one stride rule of every variant: K rays per side, spaced so that the window spans
    /// about `share` of the image's shorter side, `s = max(1, round(share · min(w, h) / K))`
    /// (`stride`, when not 0, overrides it). The result is then [`PatchSpec::fitted`] to the
    /// image, so a window that rounding made too wide loses rays, never the stride.
    pub fn spanning(
        size: u32,
        stride: u32,
        share: f32,
        width: u32,
        height: u32,
    ) -> Result<PatchSpec, DataError> {
        let stride = if stride > 0 {
            stride
        } else {
            ((share * width.min(height) as f32 / size.max(1) as f32).round() as u32).max(1)
        };
        PatchSpec::new(size, stride).fitted(width, height)
    }

    /// Window side K·s in pixels (saturating, so absurd requests cannot overflow).
    pub fn span(&self) -> u32 {
        self.size.saturating_mul(self.stride)
    }

    /// The patch that fits a `width`×`height` image: the stride is kept and K shrinks until the
    /// window fits. An error (not a panic) when not even one ray fits or K or s is 0.
    pub fn fitted(&self, width: u32, height: u32) -> Result<PatchSpec, DataError> {
        if self.size == 0 || self.stride == 0 {
            return Err(DataError::Request(format!(
                "patch size {} and stride {} must be positive",
                self.size, self.stride
            )));
        }
        let size = self.size.min(width.min(height) / self.stride);
        if size == 0 {
            return Err(DataError::Request(format!(
                "a patch with stride {} does not fit a {width}×{height} image",
                self.stride
            )));
        }
        Ok(PatchSpec {
            size,
            stride: self.stride,
        })
    }

    /// A uniformly random window origin inside a `width`×`height` image, or an error when the
    /// window does not fit.
    pub fn random_origin(
        &self,
        width: u32,
        height: u32,
        rng: &mut impl Rng,
    ) -> Result<(u32, u32), DataError> {
        let span = self.span();
        if self.size == 0 || self.stride == 0 || span > width || span > height {
            return Err(DataError::Request(format!(
                "a {k}×{k} patch with stride {s} spans {span} pixels, more than the {width}×{height} image",
                k = self.size,
                s = self.stride
            )));
        }
        Ok((
            rng.random_range(0..=width - span),
            rng.random_range(0..=height - span),
        ))
    }

    /// The K·K pixels of the window at `(x0, y0)`, row major (`j · K + i`).
    pub fn pixels(&self, x0: u32, y0: u32) -> impl Iterator<Item = (u32, u32)> + '_ {
        let (k, s) = (self.size, self.stride);
        (0..k).flat_map(move |j| (0..k).map(move |i| (x0 + i * s, y0 + j * s)))
    }
}

/// One patch: K×K rays, row major, with the window it came from.
#[derive(Clone, Debug)]
pub struct Patch {
    /// The K·K rays and targets, row major (`j · K + i` for column i, row j).
    pub batch: RayBatch,
    /// Which view.
    pub view: usize,
    /// Left column of the (K·s)-wide window.
    pub x0: u32,
    /// Top row of the window.
    pub y0: u32,
    /// The patch geometry.
    pub spec: PatchSpec,
    /// How many placements were rejected as all background before this one.
    pub redraws: usize,
}

/// Draws strided patches at random places of random views of a split.
///
/// A patch with too little of the object is redrawn (scenes without masks never are): one
/// whose every sample has mask < 0.5, or, with `min_coverage`, one where fewer than that
/// fraction of samples lie inside the mask. Up to `max_redraws` times; after that the best
/// draw so far is returned, with `redraws == max_redraws`.
#[derive(Clone, Debug)]
pub struct PatchSampler {
    /// Patch geometry.
    pub spec: PatchSpec,
    /// Redraws allowed for patches with too little of the object.
    pub max_redraws: usize,
    /// Fraction of a patch's samples that must lie inside the mask (0: at least one).
    pub min_coverage: f32,
    rng: SmallRng,
}

impl PatchSampler {
    /// A sampler of `size`×`size` patches with stride `stride`, seeded by `seed`, allowing 100
    /// redraws.
    pub fn new(size: u32, stride: u32, seed: u64) -> Self {
        PatchSampler {
            spec: PatchSpec::new(size, stride),
            max_redraws: 100,
            min_coverage: 0.0,
            rng: SmallRng::seed_from_u64(seed),
        }
    }

    /// Requires `fraction` of each patch's samples inside the mask (stylizing a masked object:
    /// the background is not the model's to paint, and in a patch's Gram matrices it is noise).
    pub fn with_min_coverage(mut self, fraction: f32) -> Self {
        self.min_coverage = fraction;
        self
    }

    /// Window side K·s in pixels.
    pub fn span(&self) -> u32 {
        self.spec.span()
    }

    /// Draws one patch from the views of `split`. Errors when the split is empty, K or s is 0,
    /// or the window does not fit the images.
    pub fn sample(&mut self, scene: &Scene, split: Split) -> Result<Patch, DataError> {
        let views = scene.views_of(split)?;
        let mut redraws = 0;
        let mut best: Option<(f32, Patch)> = None;
        loop {
            let view = views[self.rng.random_range(0..views.len())];
            let cam = &scene.views[view].camera;
            let (x0, y0) = self
                .spec
                .random_origin(cam.width, cam.height, &mut self.rng)
                .map_err(|e| DataError::Request(format!("view {view}: {e}")))?;
            let patch = self.patch_at(scene, view, x0, y0, redraws)?;
            let inside = patch.batch.mask.iter().filter(|&&m| m >= 0.5).count();
            let coverage = inside as f32 / patch.batch.mask.len().max(1) as f32;
            if inside > 0 && coverage >= self.min_coverage {
                return Ok(patch);
            }
            if best.as_ref().is_none_or(|(c, _)| coverage > *c) {
                best = Some((coverage, patch));
            }
            if redraws >= self.max_redraws {
                let (_, mut patch) = best.expect("at least one draw");
                patch.redraws = redraws;
                return Ok(patch);
            }
            redraws += 1;
        }
    }

    /// The patch whose window starts at `(x0, y0)` in view `view`.
    pub fn patch_at(
        &self,
        scene: &Scene,
        view: usize,
        x0: u32,
        y0: u32,
        redraws: usize,
    ) -> Result<Patch, DataError> {
        let pixels: Vec<PixelRef> = self
            .spec
            .pixels(x0, y0)
            .map(|(x, y)| PixelRef { view, x, y })
            .collect();
        Ok(Patch {
            batch: scene.gather(&pixels)?,
            view,
            x0,
            y0,
            spec: self.spec,
            redraws,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stride_rule_spans_the_share_of_the_shorter_side_and_fits() {
        // 0.6 of 200 px with 64 rays: 1.875 → 2.
        assert_eq!(
            PatchSpec::spanning(64, 0, 0.6, 200, 200).unwrap(),
            PatchSpec::new(64, 2)
        );
        // 0.5 of 300 px: 2.34 → 2; an explicit stride wins.
        assert_eq!(
            PatchSpec::spanning(64, 0, 0.5, 400, 300).unwrap(),
            PatchSpec::new(64, 2)
        );
        assert_eq!(
            PatchSpec::spanning(64, 3, 0.5, 400, 300).unwrap(),
            PatchSpec::new(64, 3)
        );
        // The whole of 192 px with 128 rays rounds to stride 2: the patch shrinks to 96 rays.
        assert_eq!(
            PatchSpec::spanning(128, 0, 1.0, 256, 192).unwrap(),
            PatchSpec::new(96, 2)
        );
        assert_eq!(
            PatchSpec::spanning(128, 0, 1.0, 256, 256).unwrap(),
            PatchSpec::new(128, 2)
        );
    }

    #[test]
    fn fitting_shrinks_k_and_never_underflows() {
        let p = PatchSpec::new(128, 2).fitted(100, 60).unwrap();
        assert_eq!(p, PatchSpec::new(30, 2));
        assert!(p.span() <= 60);
        // Tiny requests and huge strides are errors, not panics.
        assert!(PatchSpec::new(8, 1).fitted(5, 5).is_ok());
        assert!(PatchSpec::new(8, 1000).fitted(64, 64).is_err());
        assert!(PatchSpec::new(0, 1).fitted(64, 64).is_err());
        assert!(PatchSpec::new(u32::MAX, u32::MAX).fitted(64, 64).is_err());
        let mut rng = SmallRng::seed_from_u64(0);
        assert!(
            PatchSpec::new(40, 2)
                .random_origin(64, 64, &mut rng)
                .is_err()
        );
        assert!(
            PatchSpec::new(u32::MAX, 2)
                .random_origin(64, 64, &mut rng)
                .is_err()
        );
    }

    #[test]
    fn windows_stay_inside_the_image() {
        let mut rng = SmallRng::seed_from_u64(1);
        let p = PatchSpec::new(7, 3);
        for _ in 0..500 {
            let (x0, y0) = p.random_origin(30, 22, &mut rng).unwrap();
            let px: Vec<_> = p.pixels(x0, y0).collect();
            assert_eq!(px.len(), 49);
            assert!(px.iter().all(|&(x, y)| x < 30 && y < 22));
            assert_eq!(px[1].0 - px[0].0, 3);
            assert_eq!(px[7].1 - px[0].1, 3);
        }
    }
}
