//! Rays of a scene's cameras, and batches of (ray, colour, mask) triples for training.
//!
//! Everything is plain `Vec<Vec3>` / `Vec<f32>` on the host; [`flatten`] gives the `[n, 3]`
//! row-major layout a tensor wants.

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::camera::Camera;
use super::geometry::Vec3;
use crate::data::{DataError, Scene, Split};

/// A set of rays in the scene frame: unit directions and a parameter interval each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rays {
    /// Ray origins.
    pub origins: Vec<Vec3>,
    /// Unit ray directions (not unit after [`Rays::to_ndc`]).
    pub directions: Vec<Vec3>,
    /// Start of each ray's interval: the point `o + near·d`.
    pub near: Vec<f32>,
    /// End of each ray's interval.
    pub far: Vec<f32>,
}

impl Rays {
    /// Empty set with room for `n` rays.
    pub fn with_capacity(n: usize) -> Self {
        Rays {
            origins: Vec::with_capacity(n),
            directions: Vec::with_capacity(n),
            near: Vec::with_capacity(n),
            far: Vec::with_capacity(n),
        }
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    /// Whether there are no rays.
    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    /// Appends one ray.
    pub fn push(&mut self, origin: Vec3, direction: Vec3, near: f32, far: f32) {
        self.origins.push(origin);
        self.directions.push(direction);
        self.near.push(near);
        self.far.push(far);
    }

    /// Point `o + t·d` on ray `i`.
    pub fn point(&self, i: usize, t: f32) -> Vec3 {
        self.origins[i] + t * self.directions[i]
    }

    /// Rays in normalized device coordinates for forward-facing (LLFF) scenes, as in NeRF's
    /// `ndc_rays`: the frustum of a camera looking down −z with the given image size and focal
    /// length maps to the cube `[-1, 1]³`, depth `near_plane … ∞` to `t ∈ [0, 1]`. Use it with the
    /// LLFF scene frame, where the mean camera looks down −z. Directions are not unit here.
    pub fn to_ndc(&self, width: u32, height: u32, focal: f32, near_plane: f32) -> Rays {
        let (w, h) = (width as f32, height as f32);
        let mut out = Rays::with_capacity(self.len());
        for i in 0..self.len() {
            let (o, d) = (self.origins[i], self.directions[i]);
            let t = -(near_plane + o.z) / d.z;
            let o = o + t * d;
            let o_ndc = Vec3::new(
                -2.0 * focal / w * o.x / o.z,
                -2.0 * focal / h * o.y / o.z,
                1.0 + 2.0 * near_plane / o.z,
            );
            let d_ndc = Vec3::new(
                -2.0 * focal / w * (d.x / d.z - o.x / o.z),
                -2.0 * focal / h * (d.y / d.z - o.y / o.z),
                -2.0 * near_plane / o.z,
            );
            out.push(o_ndc, d_ndc, 0.0, 1.0);
        }
        out
    }
}

/// Points or directions as the `[n, 3]` row-major values a tensor takes.
pub fn flatten(v: &[Vec3]) -> Vec<f32> {
    v.iter().flat_map(|p| p.to_array()).collect()
}

/// Which pixel a ray belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PixelRef {
    /// Index into [`Scene::views`].
    pub view: usize,
    /// Column (0 = left).
    pub x: u32,
    /// Row (0 = top).
    pub y: u32,
}

/// Rays with their training targets: what a trainer pulls for each step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayBatch {
    /// The rays (through pixel centres).
    pub rays: Rays,
    /// Target colour in `[0, 1]` (Blender images already composited on white).
    pub rgb: Vec<[f32; 3]>,
    /// Foreground weight in `[0, 1]`: the mask or alpha, or 1 where the scene has none.
    pub mask: Vec<f32>,
    /// Where each ray came from.
    pub pixels: Vec<PixelRef>,
}

impl RayBatch {
    /// Number of rays.
    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    /// Whether the batch is empty.
    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }
}

/// Rays through the centres of all pixels of `camera`, row major, each with interval
/// `range(o, d)`.
pub fn camera_rays(camera: &Camera, range: impl Fn(Vec3, Vec3) -> (f32, f32)) -> Rays {
    let n = camera.width as usize * camera.height as usize;
    let mut rays = Rays::with_capacity(n);
    let rot = camera.rotation();
    let o = camera.origin();
    for v in 0..camera.height {
        for u in 0..camera.width {
            let dc = camera.direction_camera(u as f32 + 0.5, v as f32 + 0.5);
            let d = (rot * dc).normalize_or_zero();
            let (near, far) = range(o, d);
            rays.push(o, d, near, far);
        }
    }
    rays
}

impl Scene {
    /// Rays through every pixel of view `view`, row major (`y · width + x`).
    pub fn view_rays(&self, view: usize) -> Result<Rays, DataError> {
        let v = self.views.get(view).ok_or_else(|| self.bad_view(view))?;
        Ok(camera_rays(&v.camera, |o, d| self.ray_range(o, d)))
    }

    /// Rays through the centres of the given pixels `(x, y)` of view `view`.
    pub fn pixel_rays(&self, view: usize, pixels: &[(u32, u32)]) -> Result<Rays, DataError> {
        let v = self.views.get(view).ok_or_else(|| self.bad_view(view))?;
        let mut rays = Rays::with_capacity(pixels.len());
        for &(x, y) in pixels {
            if x >= v.camera.width || y >= v.camera.height {
                return Err(DataError::Request(format!(
                    "pixel ({x}, {y}) is outside view {view} ({}×{}, {})",
                    v.camera.width,
                    v.camera.height,
                    v.path.display()
                )));
            }
            let (o, d) = v.camera.pixel_ray(x, y);
            let (near, far) = self.ray_range(o, d);
            rays.push(o, d, near, far);
        }
        Ok(rays)
    }

    /// Rays and targets (colour, mask) of the given pixels. Pixels outside their view, or of a
    /// view that does not exist, give an error.
    pub fn gather(&self, pixels: &[PixelRef]) -> Result<RayBatch, DataError> {
        let mut batch = RayBatch {
            rays: Rays::with_capacity(pixels.len()),
            rgb: Vec::with_capacity(pixels.len()),
            mask: Vec::with_capacity(pixels.len()),
            pixels: Vec::with_capacity(pixels.len()),
        };
        for &p in pixels {
            let v = self
                .views
                .get(p.view)
                .ok_or_else(|| self.bad_view(p.view))?;
            if p.x >= v.camera.width || p.y >= v.camera.height {
                return Err(DataError::Request(format!(
                    "pixel ({}, {}) is outside view {}",
                    p.x, p.y, p.view
                )));
            }
            let (o, d) = v.camera.pixel_ray(p.x, p.y);
            let (near, far) = self.ray_range(o, d);
            batch.rays.push(o, d, near, far);
            batch.rgb.push(v.image.rgb(p.x, p.y));
            batch
                .mask
                .push(v.mask.as_ref().map_or(1.0, |m| m.value(p.x, p.y)));
            batch.pixels.push(p);
        }
        Ok(batch)
    }

    pub(crate) fn bad_view(&self, view: usize) -> DataError {
        DataError::Request(format!(
            "view {view} does not exist ({} views in {})",
            self.views.len(),
            self.root.display()
        ))
    }
}

/// Draws random pixels uniformly over the views of a split (first a view, then a pixel), the
/// classic NeRF batch. Owns its random generator so a seed makes it reproducible.
#[derive(Clone, Debug)]
pub struct RaySampler {
    /// Rays per batch.
    pub batch_size: usize,
    rng: SmallRng,
}

impl RaySampler {
    /// A sampler of `batch_size` rays seeded by `seed`.
    pub fn new(batch_size: usize, seed: u64) -> Self {
        RaySampler {
            batch_size,
            rng: SmallRng::seed_from_u64(seed),
        }
    }

    /// One batch from the views of `split`.
    pub fn sample(&mut self, scene: &Scene, split: Split) -> Result<RayBatch, DataError> {
        let views = scene.views_of(split)?;
        let mut pixels = Vec::with_capacity(self.batch_size);
        for _ in 0..self.batch_size {
            let view = views[self.rng.random_range(0..views.len())];
            let cam = &scene.views[view].camera;
            pixels.push(PixelRef {
                view,
                x: self.rng.random_range(0..cam.width.max(1)),
                y: self.rng.random_range(0..cam.height.max(1)),
            });
        }
        scene.gather(&pixels)
    }
}
