//! The one scene type every loader produces: posed images, depth bounds, a bounding volume and
//! train/val/test splits.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::Serialize;

use super::error::DataError;
use super::images::{Image, Mask};
use crate::camera::Camera;
use crate::geometry::{Bounds, Contraction, Similarity, Vec3};

/// The on-disk format a scene was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SceneFormat {
    /// NeRF-synthetic: `transforms_{train,val,test}.json` + RGBA images.
    Blender,
    /// LLFF: `poses_bounds.npy` + `images/` or `images_N/`.
    Llff,
    /// DTU in the IDR/NeuS layout: `cameras.npz` / `cameras_sphere.npz`, `image/`, `mask/`.
    Dtu,
    /// A COLMAP workspace: `sparse/0/{cameras,images,points3D}.{bin,txt}` + `images/`.
    Colmap,
    /// An instant-ngp / nerfstudio capture: one `transforms.json` (Polycam, Record3D and
    /// `ns-process-data` write it too).
    Transforms,
}

impl fmt::Display for SceneFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SceneFormat::Blender => "blender",
            SceneFormat::Llff => "llff",
            SceneFormat::Dtu => "dtu",
            SceneFormat::Colmap => "colmap",
            SceneFormat::Transforms => "transforms",
        })
    }
}

impl FromStr for SceneFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "blender" | "nerf_synthetic" | "synthetic" => Ok(SceneFormat::Blender),
            "llff" => Ok(SceneFormat::Llff),
            "dtu" | "idr" | "neus" => Ok(SceneFormat::Dtu),
            "colmap" => Ok(SceneFormat::Colmap),
            "transforms" | "nerfstudio" | "instant-ngp" | "ngp" => Ok(SceneFormat::Transforms),
            _ => Err(format!(
                "unknown scene format {s:?} (expected blender, llff, dtu, colmap or transforms)"
            )),
        }
    }
}

/// A subset of a scene's views.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Training views.
    Train,
    /// Validation views.
    Val,
    /// Test views.
    Test,
}

impl Split {
    /// All three, in order.
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        })
    }
}

impl FromStr for Split {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "train" => Ok(Split::Train),
            "val" | "validation" => Ok(Split::Val),
            "test" => Ok(Split::Test),
            _ => Err(format!("unknown split {s:?} (expected train, val or test)")),
        }
    }
}

/// One posed image.
#[derive(Clone, Debug)]
pub struct View {
    /// Its camera, in the scene frame.
    pub camera: Camera,
    /// RGB (Blender images composited on white).
    pub image: Image,
    /// Object mask (DTU) or alpha (Blender), same size as the image.
    pub mask: Option<Mask>,
    /// The image file.
    pub path: PathBuf,
    /// The mask file, when the mask came from its own file.
    pub mask_path: Option<PathBuf>,
    /// Per-view depth bounds in the scene frame (LLFF's `poses_bounds.npy` columns 15–16).
    pub depth_range: Option<(f32, f32)>,
}

/// How to read a scene.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Integer downscale factor for images and intrinsics (1 = full size). LLFF uses
    /// `images_N/` when it exists.
    pub downscale: u32,
    /// Only these splits' images are read, where the format keeps splits in separate files
    /// (Blender); `None` reads all.
    pub splits: Option<Vec<Split>>,
    /// LLFF, COLMAP and transforms.json: every `llff_hold`-th view (starting with 0) is held
    /// out for test (and val); 0 holds none out. Default 8.
    pub llff_hold: usize,
    /// LLFF: the poses are rescaled so the nearest depth bound becomes `1 / bd_factor`.
    /// Default 0.75.
    pub bd_factor: f32,
    /// COLMAP: the folder of the images the model names (default `images/` beside `sparse/`).
    pub image_dir: Option<PathBuf>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            downscale: 1,
            splits: None,
            llff_hold: 8,
            bd_factor: 0.75,
            image_dir: None,
        }
    }
}

impl LoadOptions {
    /// Whether the images of `split` are wanted.
    pub fn wants(&self, split: Split) -> bool {
        self.splits.as_ref().is_none_or(|s| s.contains(&split))
    }
}

/// Posed images of one scene, in one camera convention (see [`crate::camera`]).
#[derive(Clone, Debug)]
pub struct Scene {
    /// Folder name.
    pub name: String,
    /// Format it was read from.
    pub format: SceneFormat,
    /// The folder.
    pub root: PathBuf,
    /// All views; splits index into this.
    pub views: Vec<View>,
    /// Training views.
    pub train: Vec<usize>,
    /// Validation views.
    pub val: Vec<usize>,
    /// Test views.
    pub test: Vec<usize>,
    /// Scene-wide ray start distance.
    pub near: f32,
    /// Scene-wide ray end distance.
    pub far: f32,
    /// The volume that holds the scene.
    pub bounds: Bounds,
    /// When true, each ray's interval is where it crosses [`Scene::bounds`] (DTU's unit
    /// sphere) instead of `[near, far]`.
    pub per_ray_range: bool,
    /// Map from the dataset's own world frame to the scene frame (identity for Blender; LLFF
    /// rescale + recentre; DTU `scale_mat⁻¹`).
    pub to_scene: Similarity,
    /// Whether images were composited on a white background (Blender).
    pub white_background: bool,
    /// Forward-facing (LLFF, and captures whose cameras all look one way): rendered in NDC,
    /// where depth runs from the near plane to infinity.
    pub forward_facing: bool,
    /// Unbounded captures (a subject in a room or a street): space beyond [`Scene::bounds`]
    /// is contracted into a cube the field covers, and rays run out to [`Scene::far`].
    pub contraction: Option<Contraction>,
    /// The capture's sparse points (SfM's, or a transforms.json's point cloud) in the scene
    /// frame; empty for formats that have none (DTU, Blender, LLFF).
    pub points: Vec<Vec3>,
    /// What a user should know about how the folder was read, one sentence each (photos a
    /// `transforms.json` names that are not there): printed by `data check` and by training.
    pub notes: Vec<String>,
}

impl Scene {
    /// About `max` colours of the split's photos, a regular subsample of their pixels, on the
    /// object where the views have masks: the scene's palette.
    pub fn object_colors(&self, split: Split, max: usize) -> Vec<[f32; 3]> {
        let views = self.split(split);
        let total: usize = views
            .iter()
            .map(|&i| (self.views[i].image.width * self.views[i].image.height) as usize)
            .sum();
        let stride = (total / max.max(1)).max(1);
        let mut out = Vec::with_capacity(max);
        let mut k = 0usize;
        for &i in views {
            let v = &self.views[i];
            let (w, h) = (v.image.width, v.image.height);
            for y in 0..h {
                for x in 0..w {
                    k += 1;
                    if !k.is_multiple_of(stride) {
                        continue;
                    }
                    if v.mask.as_ref().is_none_or(|m| m.value(x, y) > 0.5) {
                        out.push(v.image.rgb(x, y));
                    }
                }
            }
        }
        out
    }

    /// View indices of a split.
    pub fn split(&self, split: Split) -> &[usize] {
        match split {
            Split::Train => &self.train,
            Split::Val => &self.val,
            Split::Test => &self.test,
        }
    }

    /// View indices of a split, or an error naming the scene when it has none (samplers need
    /// at least one view to draw from).
    pub fn views_of(&self, split: Split) -> Result<&[usize], DataError> {
        let views = self.split(split);
        if views.is_empty() {
            return Err(DataError::Request(format!(
                "split {split} of {} has no views",
                self.root.display()
            )));
        }
        Ok(views)
    }

    /// Interval `(near, far)` of the ray `o + t·d` (unit `d`). With [`Scene::per_ray_range`]:
    /// where it crosses the bounding volume (near clamped at 0); a ray that misses gets the
    /// NeuS fallback `[c − r, c + r]` around its closest approach `c` to the centre (radius `r`
    /// of the volume's bounding sphere). Otherwise the scene's `(near, far)`.
    pub fn ray_range(&self, o: Vec3, d: Vec3) -> (f32, f32) {
        if !self.per_ray_range {
            return (self.near, self.far);
        }
        if let Some((t0, t1)) = self.bounds.intersect(o, d)
            && t1 > 0.0
        {
            return (t0.max(0.0), t1);
        }
        let c = self.bounds.center();
        let r = match self.bounds {
            Bounds::Sphere { radius, .. } => radius,
            Bounds::Aabb { min, max } => 0.5 * (max - min).length(),
        };
        let mid = (c - o).dot(d);
        ((mid - r).max(0.0), (mid + r).max(0.0))
    }

    /// Size `(width, height)` of the first view, `(0, 0)` without views. A capture's views may
    /// differ in size ([`Self::smallest_resolution`]); this is the size a camera path shares.
    pub fn resolution(&self) -> (u32, u32) {
        self.views
            .first()
            .map_or((0, 0), |v| (v.camera.width, v.camera.height))
    }

    /// The smallest width and the smallest height over the views (of a capture whose photos
    /// differ in size or orientation): what a window drawn from any view must fit in.
    /// `(0, 0)` without views.
    pub fn smallest_resolution(&self) -> (u32, u32) {
        let w = self.views.iter().map(|v| v.camera.width).min();
        let h = self.views.iter().map(|v| v.camera.height).min();
        (w.unwrap_or(0), h.unwrap_or(0))
    }

    /// Whether any view has a mask.
    pub fn has_masks(&self) -> bool {
        self.views.iter().any(|v| v.mask.is_some())
    }

    /// Path of the folder, for messages.
    pub fn root(&self) -> &Path {
        &self.root
    }
}
