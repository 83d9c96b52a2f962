//! COLMAP workspaces: a sparse model (`sparse/0/`, `sparse/`, `colmap/sparse/0/` or the folder
//! itself) and the photos it names (`images/` beside it, or [`LoadOptions::image_dir`]).
//!
//! COLMAP stores world-to-camera poses (quaternion `qvec` + `tvec`, OpenCV axes); a camera's
//! centre is `−Rᵀ t` and its camera-to-world rotation `Rᵀ`, turned to OpenGL axes by flipping
//! the y and z columns. Images are listed by name, as `images.txt` readers conventionally do, so
//! the hold-out is the same however COLMAP numbered them.
//!
//! Object masks, where a workspace has them, are in `masks/` beside the photos, named as
//! COLMAP's own `--ImageReader.mask_path` reads them (`NAME.png` for the photo `NAME`) or with
//! the photo's stem (`frame_001.png` for `frame_001.jpg`); a `masks/` folder that lacks a
//! photo's mask is an error naming it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};

use super::DataError;
use super::capture::{self, Frame, SparsePoints};
use super::colmap_model::{ColmapImage, read_model};
use super::framing::Pose;
use super::scene::{LoadOptions, Scene, SceneFormat};

/// Where a workspace's sparse model may be, in the order they are tried.
const MODEL_DIRS: [&str; 4] = ["sparse/0", "sparse", "colmap/sparse/0", "."];

/// The folder of the sparse model in workspace `dir`, if there is one.
pub fn find_model(dir: &Path) -> Option<PathBuf> {
    MODEL_DIRS
        .iter()
        .map(|m| dir.join(m))
        .find(|m| super::colmap_model::model_encoding(m).is_some())
}

/// Largest deviation of a quaternion's norm from 1 that is read as rounding.
const QUATERNION_TOLERANCE: f64 = 1e-3;

/// Camera-to-world (OpenGL axes) of a COLMAP image.
pub fn image_pose(img: &ColmapImage) -> Result<Pose, String> {
    let [w, x, y, z] = img.qvec;
    let q = DQuat::from_xyzw(x, y, z, w);
    let norm = q.length();
    if !((norm - 1.0).abs() <= QUATERNION_TOLERANCE) {
        return Err(format!(
            "rotation quaternion has norm {norm} (not a rotation)"
        ));
    }
    let r = DMat3::from_quat(q.normalize());
    let rt = r.transpose();
    let centre = -(rt * DVec3::from_array(img.tvec));
    let mut c2w = [[0.0; 4]; 3];
    for (row, out) in c2w.iter_mut().enumerate() {
        // Rᵀ's columns are the camera's x, y, z axes (OpenCV); OpenGL flips y and z.
        *out = [
            rt.col(0)[row],
            -rt.col(1)[row],
            -rt.col(2)[row],
            centre[row],
        ];
    }
    Ok(c2w)
}

/// Reads the COLMAP workspace `dir`.
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let model_dir = find_model(dir).ok_or_else(|| {
        DataError::missing(
            &dir.join("sparse/0"),
            "COLMAP sparse model (cameras.bin or cameras.txt)",
        )
    })?;
    let model = read_model(&model_dir)?;
    let ext = super::colmap_model::model_encoding(&model_dir).map_or("bin", |e| match e {
        super::colmap_model::Encoding::Binary => "bin",
        super::colmap_model::Encoding::Text => "txt",
    });
    let images_file = model_dir.join(format!("images.{ext}"));
    let image_dir = opts
        .image_dir
        .clone()
        .unwrap_or_else(|| image_folder(dir, &model_dir));
    if !image_dir.is_dir() {
        return Err(DataError::missing(
            &image_dir,
            "image folder of the COLMAP model",
        ));
    }
    if model.images.is_empty() {
        return Err(DataError::invalid(&images_file, "no registered images"));
    }

    let point_index: HashMap<u64, usize> = model
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| (p.id, i))
        .collect();
    let mask_dir = image_dir
        .parent()
        .map(|p| p.join("masks"))
        .filter(|d| d.is_dir());
    let mut images: Vec<&ColmapImage> = model.images.iter().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut frames = Vec::with_capacity(images.len());
    let mut visible = Vec::with_capacity(images.len());
    for img in images {
        let origin = format!("image {} ({})", img.id, img.name);
        let cam = model.cameras.get(&img.camera_id).ok_or_else(|| {
            DataError::invalid(
                &images_file,
                format!(
                    "{origin} names camera {}, which is not in {}",
                    img.camera_id,
                    model_dir.join(format!("cameras.{ext}")).display()
                ),
            )
        })?;
        let c2w = image_pose(img)
            .map_err(|e| DataError::invalid(&images_file, format!("{origin}: {e}")))?;
        let path = image_dir.join(&img.name);
        if !path.is_file() {
            return Err(DataError::missing(
                &path,
                format!("the photo of {origin} in {}", images_file.display()),
            ));
        }
        let mask = match &mask_dir {
            Some(d) => Some(mask_file(d, &img.name).ok_or_else(|| {
                DataError::missing(
                    &d.join(format!("{}.png", img.name)),
                    format!("the mask of {origin} (the workspace has a masks/ folder)"),
                )
            })?),
            None => None,
        };
        let (intrinsics, distortion) = cam.intrinsics();
        frames.push(Frame {
            image: path,
            mask,
            size: (cam.width, cam.height),
            intrinsics,
            distortion,
            c2w,
            origin: format!(
                "{}: {origin}, camera {} of {}",
                images_file.display(),
                cam.id,
                model_dir.join(format!("cameras.{ext}")).display()
            ),
        });
        visible.push(
            img.points2d
                .iter()
                .filter_map(|&(_, id)| {
                    u64::try_from(id)
                        .ok()
                        .and_then(|id| point_index.get(&id).copied())
                })
                .collect(),
        );
    }
    let sparse = SparsePoints {
        points: model
            .points
            .iter()
            .map(|p| DVec3::from_array(p.xyz))
            .collect(),
        visible,
    };
    capture::build(
        SceneFormat::Colmap,
        dir,
        &images_file,
        frames,
        &sparse,
        None,
        opts,
    )
}

/// The mask of the photo `name` in `dir`: `NAME.png` (COLMAP's convention), else the photo's
/// stem with `.png`, else the same file name.
fn mask_file(dir: &Path, name: &str) -> Option<PathBuf> {
    let stem = Path::new(name).with_extension("png");
    [
        dir.join(format!("{name}.png")),
        dir.join(stem),
        dir.join(name),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

/// `images/` in the workspace, else beside the model folder's parent chain (`sparse/0/../../images`).
fn image_folder(dir: &Path, model_dir: &Path) -> PathBuf {
    let direct = dir.join("images");
    if direct.is_dir() {
        return direct;
    }
    model_dir
        .ancestors()
        .skip(1)
        .map(|a| a.join("images"))
        .find(|p| p.is_dir())
        .unwrap_or(direct)
}
