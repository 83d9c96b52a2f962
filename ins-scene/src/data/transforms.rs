//! instant-ngp / nerfstudio captures: one `transforms.json` with camera-to-world matrices in
//! OpenGL axes, intrinsics for the scene or per frame (`fl_x fl_y cx cy w h`, or
//! `camera_angle_x`), the lens (`camera_model` OPENCV or OPENCV_FISHEYE with `k1 k2 k3 k4 p1
//! p2`), `file_path` with or without an extension relative to the file, optional `mask_path`,
//! `aabb_scale` and `ply_file_path` (nerfstudio's sparse points). Frames are listed by file
//! name. nerfstudio's `ns-process-data`, Polycam and Record3D exports write it.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::DataError;
use super::capture::{self, Frame, SparsePoints};
use super::ply_points::read_ply_points;
use super::scene::{LoadOptions, Scene, SceneFormat};
use crate::distortion::Distortion;

/// The file name.
pub const FILE: &str = "transforms.json";

/// Extensions tried, in order, for a `file_path` written without one.
const EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"];

/// Fewest photos a capture may keep when some its file names are missing: fewer cannot be
/// trained and held out from (public captures are often shared without some of their photos,
/// and a user would rather train on those present).
pub const MIN_PRESENT: usize = 3;

/// Reads the capture whose `transforms.json` is in `dir`.
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let path = dir.join(FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| DataError::io(&path, e))?;
    let json: Value =
        serde_json::from_str(&text).map_err(|e| DataError::json(&path, e.to_string()))?;
    if !json.is_object() {
        return Err(DataError::json(&path, "top level is not an object"));
    }
    let frames_json = json
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| DataError::json(&path, "missing frames array"))?;
    let aabb_scale = match json.get("aabb_scale") {
        None | Some(Value::Null) => None,
        Some(v) => Some(
            v.as_f64()
                .filter(|s| s.is_finite() && *s >= 1.0 && *s <= 128.0)
                .map(|s| (s.round() as u32).next_power_of_two())
                .ok_or_else(|| {
                    DataError::json(&path, format!("aabb_scale {v} is not a number in [1, 128]"))
                })?,
        ),
    };
    let mut frames = Vec::with_capacity(frames_json.len());
    let mut missing = Vec::new();
    for (i, f) in frames_json.iter().enumerate() {
        let err = |msg: String| DataError::json(&path, format!("frame {i}: {msg}"));
        let file = f
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| err("missing file_path".into()))?;
        let Some(image) = resolve(dir, file) else {
            missing.push(dir.join(file));
            continue;
        };
        let mask = match f.get("mask_path").and_then(Value::as_str) {
            None => None,
            Some(m) => Some(resolve(dir, m).ok_or_else(|| {
                DataError::missing(&dir.join(m), format!("the mask of frame {i} in {FILE}"))
            })?),
        };
        let c2w = f
            .get("transform_matrix")
            .and_then(matrix_3x4)
            .ok_or_else(|| err("transform_matrix is not a 4×4 array of finite numbers".into()))?;
        // Per-frame values override the scene's.
        let get = |key: &str| f.get(key).or_else(|| json.get(key));
        let lens = intrinsics(&get, &image).map_err(err)?;
        frames.push(Frame {
            image,
            mask,
            size: lens.0,
            intrinsics: lens.1,
            distortion: lens.2,
            c2w,
            origin: format!("frame {i}"),
        });
    }
    let notes = missing_photos(&path, frames_json.len(), frames.len(), &missing)?;
    // In file-name order, as nerfstudio's reader and the COLMAP reader list them (exporters
    // write frames in registration order), so the held-out views do not depend on it.
    frames.sort_by(|a, b| a.image.cmp(&b.image));
    // nerfstudio's sparse point cloud places the near plane and the box as COLMAP's does.
    let sparse = match json.get("ply_file_path").and_then(Value::as_str) {
        Some(ply) => {
            let ply_path = dir.join(ply.strip_prefix("./").unwrap_or(ply));
            if !ply_path.is_file() {
                return Err(DataError::missing(
                    &ply_path,
                    format!("the point cloud named by ply_file_path in {FILE}"),
                ));
            }
            SparsePoints {
                points: read_ply_points(&ply_path)?,
                visible: Vec::new(),
            }
        }
        None => SparsePoints::default(),
    };
    let mut scene = capture::build(
        SceneFormat::Transforms,
        dir,
        &path,
        frames,
        &sparse,
        aabb_scale,
        opts,
    )?;
    scene.notes.extend(notes);
    Ok(scene)
}

/// What to say of the photos `missing` among the `named` frames of `path`: nothing when all
/// are there; a note naming how many are missing (and the first) when at least
/// [`MIN_PRESENT`] remain; else an error naming the first missing photo.
fn missing_photos(
    path: &Path,
    named: usize,
    present: usize,
    missing: &[PathBuf],
) -> Result<Vec<String>, DataError> {
    let Some(first) = missing.first() else {
        return Ok(Vec::new());
    };
    if present < MIN_PRESENT {
        return Err(DataError::missing(
            first,
            format!(
                "{} of the {named} photos {FILE} names are missing, this one among them; \
                 {present} remain, and a capture needs at least {MIN_PRESENT}",
                missing.len()
            ),
        ));
    }
    Ok(vec![format!(
        "{} of the {named} photos {} names are missing (the first: {}); training on the {present} present",
        missing.len(),
        path.display(),
        first.display()
    )])
}

/// The full-size resolution of the first frame, from `w`/`h` or the image's header, without
/// decoding any image.
pub fn probe_resolution(dir: &Path) -> Result<(u32, u32), DataError> {
    let path = dir.join(FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| DataError::io(&path, e))?;
    let json: Value =
        serde_json::from_str(&text).map_err(|e| DataError::json(&path, e.to_string()))?;
    let frames = json
        .get("frames")
        .and_then(Value::as_array)
        .filter(|f| !f.is_empty())
        .ok_or_else(|| DataError::json(&path, "missing frames array"))?;
    // The first frame whose photo is there (photos may be missing: see `missing_photos`).
    fn file_of(f: &Value) -> Option<&str> {
        f.get("file_path").and_then(Value::as_str)
    }
    let Some((i, first, image)) = frames.iter().enumerate().find_map(|(i, f)| {
        let image = resolve(dir, file_of(f)?)?;
        Some((i, f, image))
    }) else {
        let file = file_of(&frames[0])
            .ok_or_else(|| DataError::json(&path, "frame 0: missing file_path"))?;
        return Err(DataError::missing(
            &dir.join(file),
            format!("the image of frame 0 in {FILE} (no photo it names is there)"),
        ));
    };
    let get = |key: &str| first.get(key).or_else(|| json.get(key));
    intrinsics(&get, &image)
        .map(|lens| lens.0)
        .map_err(|e| DataError::json(&path, format!("frame {i}: {e}")))
}

type Lens = ((u32, u32), [f64; 4], Distortion);

/// Size, `fx fy cx cy` and lens of a frame from the keys `get` finds (frame, then scene).
fn intrinsics<'a>(get: &dyn Fn(&str) -> Option<&'a Value>, image: &Path) -> Result<Lens, String> {
    let num = |key: &str| -> Result<Option<f64>, String> {
        match get(key) {
            None | Some(Value::Null) => Ok(None),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| format!("{key} is not a finite number")),
        }
    };
    let size = match (num("w")?, num("h")?) {
        (Some(w), Some(h)) if w >= 1.0 && h >= 1.0 && w <= 65536.0 && h <= 65536.0 => {
            (w as u32, h as u32)
        }
        (None, None) | (Some(_), None) | (None, Some(_)) => ::image::image_dimensions(image)
            .map_err(|e| format!("no w and h given and {}: {e}", image.display()))?,
        (w, h) => return Err(format!("image size {w:?} × {h:?} is not valid")),
    };
    let (w, h) = (size.0 as f64, size.1 as f64);
    let fx = match (num("fl_x")?, num("camera_angle_x")?) {
        (Some(f), _) => f,
        (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => 0.5 * w / (0.5 * a).tan(),
        (None, Some(a)) => return Err(format!("camera_angle_x = {a} is not an angle in (0, π)")),
        (None, None) => return Err("neither fl_x nor camera_angle_x given".into()),
    };
    let fy = match (num("fl_y")?, num("camera_angle_y")?) {
        (Some(f), _) => f,
        (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => 0.5 * h / (0.5 * a).tan(),
        _ => fx,
    };
    let cx = num("cx")?.unwrap_or(0.5 * w);
    let cy = num("cy")?.unwrap_or(0.5 * h);
    let k = |key: &str| num(key).map(|v| v.unwrap_or(0.0));
    let model = get("camera_model")
        .and_then(Value::as_str)
        .unwrap_or("OPENCV");
    let fisheye = get("is_fisheye").and_then(Value::as_bool).unwrap_or(false);
    let distortion = match (model, fisheye) {
        ("OPENCV_FISHEYE", _) | (_, true) => Distortion::Fisheye {
            k: [k("k1")?, k("k2")?, k("k3")?, k("k4")?],
        },
        ("OPENCV" | "PINHOLE" | "SIMPLE_PINHOLE", _) => {
            if k("k4")? != 0.0 {
                return Err(
                    "k4 (nerfstudio's r⁸ term) is not supported for the OPENCV model".into(),
                );
            }
            Distortion::Polynomial {
                k: [k("k1")?, k("k2")?, k("k3")?, 0.0, 0.0, 0.0],
                p: [k("p1")?, k("p2")?],
            }
        }
        (other, _) => {
            return Err(format!(
                "camera_model {other} is not supported (OPENCV, OPENCV_FISHEYE or PINHOLE)"
            ));
        }
    };
    let distortion = if distortion.is_none() {
        Distortion::None
    } else {
        distortion
    };
    Ok((size, [fx, fy, cx, cy], distortion))
}

/// `dir/file`, or with an image extension added when written without one; `None` when no
/// such file exists.
fn resolve(dir: &Path, file: &str) -> Option<PathBuf> {
    let rel = file.strip_prefix("./").unwrap_or(file);
    let p = dir.join(rel);
    if p.is_file() {
        return Some(p);
    }
    EXTENSIONS.iter().find_map(|ext| {
        let mut s = p.clone().into_os_string();
        s.push(".");
        s.push(ext);
        let q = PathBuf::from(s);
        q.is_file().then_some(q)
    })
}

/// The top three rows of a 4×4 (or 3×4) JSON matrix, in f64.
pub(crate) fn matrix_3x4(v: &Value) -> Option<[[f64; 4]; 3]> {
    let rows = v.as_array()?;
    if rows.len() != 4 && rows.len() != 3 {
        return None;
    }
    let mut m = [[0.0f64; 4]; 3];
    for (r, row) in rows.iter().enumerate() {
        let cols = row.as_array()?;
        if cols.len() != 4 {
            return None;
        }
        for (c, x) in cols.iter().enumerate() {
            let x = x.as_f64()?;
            if !x.is_finite() {
                return None;
            }
            if r < 3 {
                m[r][c] = x;
            }
        }
    }
    Some(m)
}
