//! Scenes: posed images in one type, read from the real dataset formats.
//!
//! [`Scene::load`] detects the format of a folder and reads it: NeRF-synthetic ([`blender`]),
//! LLFF ([`llff`]) or DTU in the IDR/NeuS layout ([`dtu`]). Single images for SIREN come from
//! [`plain_image`]. [`synthetic`] writes small analytic scenes in all three formats, and
//! [`check`] runs geometric sanity checks on a loaded scene.

pub mod blender;
pub mod check;
pub mod contact_sheet;
pub mod dtu;
pub mod error;
pub mod images;
pub mod llff;
pub mod npy;
pub mod plain_image;
pub mod scene;
pub mod synthetic;

use std::path::Path;

pub use error::DataError;
pub use images::{Image, Mask};
pub use scene::{LoadOptions, Scene, SceneFormat, Split, View};

/// The format of a scene folder, from the files that mark it: `transforms_train.json` (or
/// another `transforms_*.json`) → Blender, `poses_bounds.npy` → LLFF, `cameras.npz` /
/// `cameras_sphere.npz` → DTU.
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
    if dir.join("poses_bounds.npy").is_file() {
        return Ok(SceneFormat::Llff);
    }
    if dir.join("cameras.npz").is_file() || dir.join("cameras_sphere.npz").is_file() {
        return Ok(SceneFormat::Dtu);
    }
    Err(DataError::UnknownFormat {
        path: dir.to_path_buf(),
        msg:
            "expected transforms_train.json (Blender), poses_bounds.npy (LLFF) or cameras.npz (DTU)"
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
