//! Strided K×K ray patches: K×K rays spread over a (K·s)×(K·s) pixel window, so a VGG loss on
//! the rendered K×K patch sees a large receptive field at the cost of K² rays (INS, Sec. 3.3).

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::rays::{PixelRef, RayBatch};
use crate::data::{DataError, Scene, Split};

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
    /// Patch side K.
    pub size: u32,
    /// Stride s between neighbouring rays, in pixels.
    pub stride: u32,
    /// How many placements were rejected as all background before this one.
    pub redraws: usize,
}

/// Draws strided patches at random places of random views of a split.
///
/// Sample `(i, j)` of a patch at window origin `(x0, y0)` is the centre of pixel
/// `(x0 + i·s, y0 + j·s)`; the window `[x0, x0 + K·s) × [y0, y0 + K·s)` lies inside the image.
/// A patch whose every sample has mask < 0.5 is redrawn (scenes without masks never are), up to
/// `max_redraws` times; after that the last draw is returned, with `redraws == max_redraws`.
#[derive(Clone, Debug)]
pub struct PatchSampler {
    /// Patch side K (rays per row).
    pub size: u32,
    /// Stride s in pixels.
    pub stride: u32,
    /// Redraws allowed for all-background patches.
    pub max_redraws: usize,
    rng: SmallRng,
}

impl PatchSampler {
    /// A sampler of `size`×`size` patches with stride `stride`, seeded by `seed`, allowing 100
    /// redraws.
    pub fn new(size: u32, stride: u32, seed: u64) -> Self {
        PatchSampler {
            size,
            stride,
            max_redraws: 100,
            rng: SmallRng::seed_from_u64(seed),
        }
    }

    /// Window side K·s in pixels.
    pub fn span(&self) -> u32 {
        self.size * self.stride
    }

    /// Draws one patch from the views of `split`. Errors when the split is empty, K or s is 0,
    /// or the window does not fit the images.
    pub fn sample(&mut self, scene: &Scene, split: Split) -> Result<Patch, DataError> {
        let views = scene.split(split);
        if views.is_empty() {
            return Err(DataError::Request(format!(
                "split {split} of {} has no views",
                scene.root.display()
            )));
        }
        if self.size == 0 || self.stride == 0 {
            return Err(DataError::Request(format!(
                "patch size {} and stride {} must be positive",
                self.size, self.stride
            )));
        }
        let span = self.span();
        let mut redraws = 0;
        loop {
            let view = views[self.rng.random_range(0..views.len())];
            let cam = &scene.views[view].camera;
            if cam.width < span || cam.height < span {
                return Err(DataError::Request(format!(
                    "a {k}×{k} patch with stride {s} spans {span} pixels, more than view {view} ({}×{})",
                    cam.width,
                    cam.height,
                    k = self.size,
                    s = self.stride
                )));
            }
            let x0 = self.rng.random_range(0..=cam.width - span);
            let y0 = self.rng.random_range(0..=cam.height - span);
            let patch = self.patch_at(scene, view, x0, y0, redraws)?;
            let background = patch.batch.mask.iter().all(|&m| m < 0.5);
            if !background || redraws >= self.max_redraws {
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
        let k = self.size;
        let s = self.stride;
        let mut pixels = Vec::with_capacity((k * k) as usize);
        for j in 0..k {
            for i in 0..k {
                pixels.push(PixelRef {
                    view,
                    x: x0 + i * s,
                    y: y0 + j * s,
                });
            }
        }
        Ok(Patch {
            batch: scene.gather(&pixels)?,
            view,
            x0,
            y0,
            size: k,
            stride: s,
            redraws,
        })
    }
}
