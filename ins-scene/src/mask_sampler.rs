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
        let n_inside = inside_count(count, share);
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

    /// Each ray's weight in a term that should average over the pixels as uniform rays would
    /// (the mask's cross-entropy, which sets the silhouette): its pixel's uniform density over
    /// the density [`sample`](Self::sample) drew it with, `share` of `batch` from the masks.
    /// Unweighted, pixels just inside a mask's edge outvote those just outside (on scan37 by
    /// about 3.5 to 1 at a half share) and the silhouette swells outward.
    pub fn uniform_weights(&self, scene: &Scene, batch: &RayBatch, share: f32) -> Vec<f32> {
        let q = inside_count(batch.len(), share) as f32 / batch.len().max(1) as f32;
        batch
            .pixels
            .iter()
            .zip(&batch.mask)
            .map(|(p, &m)| {
                let slot = self.views.iter().position(|&v| v == p.view);
                let Some(inside) = slot.map(|s| &self.inside[s]) else {
                    return 1.0;
                };
                let camera = &scene.views[p.view].camera;
                let pixels = (camera.width * camera.height).max(1) as f32;
                // Drawn with density ((1 − q) + q·N/|M|·[in M]) / N; uniform is 1 / N.
                let from_mask = if inside.is_empty() || m < 0.5 {
                    0.0
                } else {
                    q * pixels / inside.len() as f32
                };
                let uniform = if inside.is_empty() { 1.0 } else { 1.0 - q };
                1.0 / (uniform + from_mask).max(f32::MIN_POSITIVE)
            })
            .collect()
    }
}

/// How many of `count` rays [`MaskedPixels::sample`] draws from the masks.
fn inside_count(count: usize, share: f32) -> usize {
    (count as f32 * share.clamp(0.0, 1.0)).round() as usize
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
        // Weighted, the rays drawn half from the masks count the object as uniform rays do.
        let b = index.sample(&scene, 4000, 0.5, 9).unwrap();
        let w = index.uniform_weights(&scene, &b, 0.5);
        let weighted = b
            .mask
            .iter()
            .zip(&w)
            .map(|(&m, &w)| (m >= 0.5) as u8 as f32 * w)
            .sum::<f32>()
            / w.iter().sum::<f32>();
        assert!((weighted - uniform).abs() < 0.04, "{weighted} vs {uniform}");
        assert!(w.iter().all(|&w| w > 0.0 && w.is_finite()));
        // Uniform rays weigh alike.
        let u = index.sample(&scene, 100, 0.0, 9).unwrap();
        assert!(
            index
                .uniform_weights(&scene, &u, 0.0)
                .iter()
                .all(|&w| w == 1.0)
        );
        // Same seed, same rays.
        assert_eq!(
            index.sample(&scene, 50, 0.5, 3).unwrap(),
            index.sample(&scene, 50, 0.5, 3).unwrap()
        );
    }
}
