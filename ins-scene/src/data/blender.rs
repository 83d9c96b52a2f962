//! NeRF-synthetic ("Blender") scenes: `transforms_{train,val,test}.json` with
//! `camera_angle_x` and per-frame `transform_matrix` (camera-to-world, already OpenGL axes),
//! RGBA images composited on white with the alpha kept as the mask.
//!
//! Bounds are the conventional ones for these scenes: rays from 2 to 6, box `[-1.5, 1.5]³`.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::DataError;
use super::images::{parallel_map, read_image};
use super::scene::{LoadOptions, Scene, SceneFormat, Split, View};
use crate::camera::Camera;
use crate::geometry::{Bounds, Similarity};

/// Near distance used for Blender scenes.
pub const NEAR: f32 = 2.0;
/// Far distance used for Blender scenes.
pub const FAR: f32 = 6.0;
/// Half side of the bounding box used for Blender scenes.
pub const HALF_EXTENT: f32 = 1.5;

/// One frame of a transforms file.
struct Frame {
    image: PathBuf,
    c2w: [[f32; 4]; 3],
}

/// Camera model shared by a transforms file.
struct Intrinsics {
    fov_x: Option<f32>,
    fl: Option<(f32, f32)>,
    c: Option<(f32, f32)>,
}

/// Reads a Blender scene from `dir`.
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let mut frames: Vec<(Split, Frame)> = Vec::new();
    let mut intr: Option<(PathBuf, Intrinsics)> = None;
    for split in Split::ALL {
        if !opts.wants(split) {
            continue;
        }
        let path = dir.join(format!("transforms_{split}.json"));
        if !path.exists() {
            let required = opts.splits.is_some() || split == Split::Train;
            if required {
                return Err(DataError::missing(
                    &path,
                    format!("camera file of the {split} split"),
                ));
            }
            continue;
        }
        let (i, fs) = read_transforms(&path, dir)?;
        if intr.is_none() {
            intr = Some((path.clone(), i));
        }
        frames.extend(fs.into_iter().map(|f| (split, f)));
    }
    let Some((intr_path, intr)) = intr else {
        return Err(DataError::missing(
            &dir.join("transforms_train.json"),
            "no transforms file",
        ));
    };
    if frames.is_empty() {
        return Err(DataError::invalid(&intr_path, "no frames"));
    }

    let paths: Vec<PathBuf> = frames.iter().map(|(_, f)| f.image.clone()).collect();
    let factor = opts.downscale.max(1);
    let decoded = parallel_map(&paths, |p| {
        let (img, alpha) = read_image(p)?.composite_on_white();
        if factor > 1 {
            Ok((
                img.width,
                img.height,
                img.downscaled(factor),
                alpha.map(|a| a.downscaled(factor)),
            ))
        } else {
            Ok((img.width, img.height, img, alpha))
        }
    })?;

    let (w0, h0) = (decoded[0].0, decoded[0].1);
    let mut views = Vec::with_capacity(frames.len());
    let (mut train, mut val, mut test) = (Vec::new(), Vec::new(), Vec::new());
    for (i, ((split, frame), (w, h, image, alpha))) in frames.into_iter().zip(decoded).enumerate() {
        if (w, h) != (w0, h0) {
            return Err(DataError::invalid(
                &frame.image,
                format!(
                    "image is {w}×{h} but {} is {w0}×{h0}: mixed image sizes",
                    paths[0].display()
                ),
            ));
        }
        let full = match (intr.fl, intr.fov_x) {
            (Some((fx, fy)), _) => {
                let (cx, cy) = intr.c.unwrap_or((0.5 * w as f32, 0.5 * h as f32));
                Camera::new(w, h, fx, fy, cx, cy, frame.c2w)
            }
            (None, Some(fov)) => {
                let mut c = Camera::from_fov_x(w, h, fov, frame.c2w);
                if let Some((cx, cy)) = intr.c {
                    c.cx = cx;
                    c.cy = cy;
                }
                c
            }
            (None, None) => {
                return Err(DataError::json(
                    &intr_path,
                    "neither camera_angle_x nor fl_x given",
                ));
            }
        };
        let camera = if factor > 1 {
            full.downscaled(factor)
        } else {
            full
        };
        match split {
            Split::Train => train.push(i),
            Split::Val => val.push(i),
            Split::Test => test.push(i),
        }
        views.push(View {
            camera,
            image,
            mask: alpha,
            path: frame.image,
            mask_path: None,
            depth_range: None,
        });
    }
    Ok(Scene {
        name: super::folder_name(dir),
        format: SceneFormat::Blender,
        root: dir.to_path_buf(),
        views,
        train,
        val,
        test,
        near: NEAR,
        far: FAR,
        bounds: Bounds::Aabb {
            min: crate::geometry::Vec3::splat(-HALF_EXTENT),
            max: crate::geometry::Vec3::splat(HALF_EXTENT),
        },
        per_ray_range: false,
        to_scene: Similarity::identity(),
        white_background: true,
        forward_facing: false,
        contraction: None,
        points: Vec::new(),
        notes: Vec::new(),
    })
}

/// Parses one transforms file into its intrinsics and frames (image paths resolved).
fn read_transforms(path: &Path, dir: &Path) -> Result<(Intrinsics, Vec<Frame>), DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    let json: Value =
        serde_json::from_str(&text).map_err(|e| DataError::json(path, e.to_string()))?;
    let num = |key: &str| -> Result<Option<f32>, DataError> {
        match json.get(key) {
            None => Ok(None),
            Some(v) => v
                .as_f64()
                .map(|x| Some(x as f32))
                .ok_or_else(|| DataError::json(path, format!("{key} is not a number"))),
        }
    };
    let fov_x = num("camera_angle_x")?;
    let fl = match (num("fl_x")?, num("fl_y")?) {
        (Some(x), Some(y)) => Some((x, y)),
        (Some(x), None) => Some((x, x)),
        _ => None,
    };
    let c = match (num("cx")?, num("cy")?) {
        (Some(x), Some(y)) => Some((x, y)),
        _ => None,
    };
    if fov_x.is_none() && fl.is_none() {
        return Err(DataError::json(path, "missing camera_angle_x"));
    }
    if let Some(f) = fov_x
        && !(f > 0.0 && f < std::f32::consts::PI)
    {
        return Err(DataError::json(
            path,
            format!("camera_angle_x = {f} is not an angle in (0, π)"),
        ));
    }
    let frames_json = json
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| DataError::json(path, "missing frames array"))?;
    let mut frames = Vec::with_capacity(frames_json.len());
    for (i, f) in frames_json.iter().enumerate() {
        let file = f
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| DataError::json(path, format!("frame {i}: missing file_path")))?;
        let m = f
            .get("transform_matrix")
            .ok_or_else(|| DataError::json(path, format!("frame {i}: missing transform_matrix")))?;
        let c2w = matrix_3x4(m).ok_or_else(|| {
            DataError::json(
                path,
                format!("frame {i}: transform_matrix is not a 4×4 array of numbers"),
            )
        })?;
        let image = resolve_image(dir, file);
        if !image.is_file() {
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            return Err(DataError::missing(
                &image,
                format!("the image of frame {i} in {name} does not exist"),
            ));
        }
        frames.push(Frame { image, c2w });
    }
    Ok((Intrinsics { fov_x, fl, c }, frames))
}

/// The top three rows of a 4×4 (or 3×4) JSON matrix.
fn matrix_3x4(v: &Value) -> Option<[[f32; 4]; 3]> {
    super::transforms::matrix_3x4(v).map(|m| m.map(|r| r.map(|x| x as f32)))
}

/// `dir/file_path`, with `.png` appended when that file does not exist as written (the NeRF
/// data gives paths without extension).
fn resolve_image(dir: &Path, file: &str) -> PathBuf {
    let rel = file.strip_prefix("./").unwrap_or(file);
    let p = dir.join(rel);
    if p.is_file() {
        return p;
    }
    let mut s = p.into_os_string();
    s.push(".png");
    PathBuf::from(s)
}
