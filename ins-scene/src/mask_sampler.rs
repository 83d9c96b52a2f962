//! Rays drawn with a chosen share inside the object masks. A surface learns its colour only
//! from rays that hit it inside the mask; on a scene where the object fills a third of the
//! frame, uniform rays spend most of a batch on background far from the object, where the mask
//! loss is already near zero.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::rays::{PixelRef, RayBatch};
use crate::data::{DataError, Scene, Split};

/// The mask pixels of every view of a split, for drawing rays inside the object.
#[derive(Debug, Clone)]
pub struct MaskedPixels {
    /// Views of the split.
    views: Vec<usize>,
    /// Per view of the split: the pixels (`y · width + x`) whose mask is at least one half.
    inside: Vec<Vec<u32>>,
}

impl MaskedPixels {
    /// Indexes the masks of `split` (a view without a mask counts as all object).
    pub fn new(scene: &Scene, split: Split) -> Result<Self, DataError> {
        let views = scene.views_of(split)?.to_vec();
        let inside = views
            .iter()
            .map(|&v| {
                let view = &scene.views[v];
                let (w, h) = (view.camera.width, view.camera.height);
                (0..w * h)
                    .filter(|&i| {
                        view.mask
                            .as_ref()
                            .is_none_or(|m| m.value(i % w, i / w) >= 0.5)
                    })
                    .collect()
            })
            .collect();
        Ok(Self { views, inside })
    }

    /// `count` rays: `share` of them (rounded) from mask pixels, the rest from all pixels, each
    /// from a view drawn uniformly. A view whose mask is empty gives any pixel.
    pub fn sample(
        &self,
        scene: &Scene,
        count: usize,
        share: f32,
        seed: u64,
    ) -> Result<RayBatch, DataError> {
        let mut rng = SmallRng::seed_from_u64(seed);
        let n_inside = (count as f32 * share.clamp(0.0, 1.0)).round() as usize;
        let mut pixels = Vec::with_capacity(count);
        for k in 0..count {
            let slot = rng.random_range(0..self.views.len());
            let view = self.views[slot];
            let w = scene.views[view].camera.width.max(1);
            let h = scene.views[view].camera.height.max(1);
            let inside = &self.inside[slot];
            let index = if k < n_inside && !inside.is_empty() {
                inside[rng.random_range(0..inside.len())]
            } else {
                rng.random_range(0..w * h)
            };
            pixels.push(PixelRef {
                view,
                x: index % w,
                y: index / w,
            });
        }
        scene.gather(&pixels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::synthetic::{SynthOptions, write_dtu};

    #[test]
    fn the_chosen_share_of_rays_lands_inside_the_masks() {
        let dir = tempfile::tempdir().unwrap();
        write_dtu(dir.path(), &SynthOptions::default()).unwrap();
        let scene = Scene::load(dir.path(), &Default::default()).unwrap();
        let index = MaskedPixels::new(&scene, Split::Train).unwrap();
        let inside = |share: f32| {
            let b = index.sample(&scene, 4000, share, 7).unwrap();
            b.mask.iter().filter(|&&m| m >= 0.5).count() as f32 / b.len() as f32
        };
        let uniform = inside(0.0);
        assert!(uniform > 0.05 && uniform < 0.9, "object share {uniform}");
        // share s inside, the rest uniform: s + (1 − s)·uniform.
        let half = inside(0.5);
        let want = 0.5 + 0.5 * uniform;
        assert!((half - want).abs() < 0.04, "{half} vs {want}");
        assert_eq!(inside(1.0), 1.0);
        // Same seed, same rays.
        assert_eq!(
            index.sample(&scene, 50, 0.5, 3).unwrap(),
            index.sample(&scene, 50, 0.5, 3).unwrap()
        );
    }
}
