//! Scenes: posed images in one type, read from the real dataset formats.
//!
//! [`Scene::load`] detects the format of a folder and reads it: NeRF-synthetic ([`blender`]),
//! LLFF ([`llff`]), DTU in the IDR/NeuS layout ([`dtu`]), and users' own captures: COLMAP
//! workspaces ([`colmap`]) and instant-ngp / nerfstudio `transforms.json` ([`transforms`]),
//! framed by [`framing`]. Single images for SIREN come from [`plain_image`]. [`synthetic`]
//! writes small analytic scenes in every format, and [`check`] runs geometric sanity checks on
//! a loaded scene.

pub mod backdrop;
pub mod blender;
pub mod capture;
pub mod check;
pub mod colmap;
pub mod colmap_model;
pub mod contact_sheet;
pub mod dtu;
pub mod error;
pub mod framing;
pub mod images;
pub mod llff;
pub mod npy;
pub mod plain_image;
pub mod ply_points;
pub mod scene;
pub mod synthetic;
pub mod transforms;
pub mod unit_sphere;

use std::path::Path;

pub use error::DataError;
pub use images::{Image, Mask};
pub use scene::{LoadOptions, Scene, SceneFormat, Split, View};

/// The format of a scene folder, from the files that mark it: `transforms_train.json` (or
/// another `transforms_*.json`) → Blender, `transforms.json` → instant-ngp / nerfstudio,
/// `poses_bounds.npy` → LLFF, `cameras.npz` / `cameras_sphere.npz` → DTU, a sparse model
/// (`sparse/0/cameras.bin`, …) → COLMAP.
pub fn detect_format(dir: &Path) -> Result<SceneFormat, DataError> {
    if !dir.is_dir() {
        return Err(DataError::missing(dir, "scene folder"));
    }
    if [
        "transforms_train.json",
        "transforms_val.json",
        "transforms_test.json",
    ]
    .iter()
    .any(|f| dir.join(f).is_file())
    {
        return Ok(SceneFormat::Blender);
    }
    if dir.join(transforms::FILE).is_file() {
        return Ok(SceneFormat::Transforms);
    }
    if dir.join("poses_bounds.npy").is_file() {
        return Ok(SceneFormat::Llff);
    }
    if dir.join("cameras.npz").is_file() || dir.join("cameras_sphere.npz").is_file() {
        return Ok(SceneFormat::Dtu);
    }
    if colmap::find_model(dir).is_some() {
        return Ok(SceneFormat::Colmap);
    }
    Err(DataError::UnknownFormat {
        path: dir.to_path_buf(),
        msg: "expected transforms_train.json (Blender), transforms.json (instant-ngp / \
              nerfstudio), sparse/0/cameras.bin (COLMAP), poses_bounds.npy (LLFF) or cameras.npz \
              (DTU); for a folder of plain photos, run `ins-cli data sfm` first"
            .into(),
    })
}

impl Scene {
    /// Reads the scene in `dir`, detecting its format.
    pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
        Scene::load_as(detect_format(dir)?, dir, opts)
    }

    /// Reads the scene in `dir` as the given format.
    pub fn load_as(
        format: SceneFormat,
        dir: &Path,
        opts: &LoadOptions,
    ) -> Result<Scene, DataError> {
        if opts.downscale == 0 {
            return Err(DataError::Request(
                "downscale factor must be at least 1".into(),
            ));
        }
        match format {
            SceneFormat::Blender => blender::load(dir, opts),
            SceneFormat::Llff => llff::load(dir, opts),
            SceneFormat::Dtu => dtu::load(dir, opts),
            SceneFormat::Colmap => colmap::load(dir, opts),
            SceneFormat::Transforms => transforms::load(dir, opts),
        }
    }

    /// The full-size resolution of the scene in `dir` without decoding its images where the
    /// format states it (COLMAP's cameras; a capture's first image header otherwise), so a
    /// 12-megapixel capture is not read twice to choose its downscale.
    pub fn probe_resolution(dir: &Path) -> Result<(u32, u32), DataError> {
        match detect_format(dir)? {
            SceneFormat::Colmap => {
                let model_dir = colmap::find_model(dir)
                    .ok_or_else(|| DataError::missing(&dir.join("sparse/0"), "COLMAP model"))?;
                let model = colmap_model::read_model(&model_dir)?;
                model
                    .cameras
                    .values()
                    .map(|c| (c.width, c.height))
                    .max_by_key(|&(w, h)| w.max(h))
                    .ok_or_else(|| DataError::invalid(&model_dir, "no cameras"))
            }
            SceneFormat::Transforms => transforms::probe_resolution(dir),
            format => {
                let probe = Scene::load_as(format, dir, &LoadOptions::default())?;
                Ok(probe.resolution())
            }
        }
    }
}

/// Last component of a folder path, for naming a scene.
pub(crate) fn folder_name(dir: &Path) -> String {
    let canonical = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    canonical
        .file_name()
        .map_or_else(|| "scene".to_string(), |n| n.to_string_lossy().into_owned())
}
