//! LLFF forward-facing scenes: `poses_bounds.npy` (N×17: a 3×5 matrix `[R | t | (H, W, f)]`
//! with rotation columns [down, right, back], then the near and far depth of the view) and the
//! images in `images/` or `images_N/`.
//!
//! The standard handling of NeRF's `load_llff_data`: columns reordered to [right, up, back]
//! (our OpenGL convention), positions and bounds rescaled so the nearest bound becomes
//! `1 / bd_factor` (0.75 → 1.33), poses recentred on their average pose, and every 8th view
//! (0, 8, 16, …) held out for test (and val, as NeRF does).

use std::path::{Path, PathBuf};

use super::DataError;
use super::framing::{forward_facing, frustum_bounds};
use super::images::{list_images, parallel_map, read_image};
use super::npy::read_npy;
use super::scene::{LoadOptions, Scene, SceneFormat, View};
use crate::camera::Camera;

/// Reads an LLFF scene from `dir`.
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let npy_path = dir.join("poses_bounds.npy");
    if !npy_path.is_file() {
        return Err(DataError::missing(&npy_path, "LLFF poses and bounds"));
    }
    let arr = read_npy(&npy_path)?;
    if arr.shape.len() != 2 || arr.shape[1] != 17 || arr.shape[0] == 0 {
        return Err(DataError::npy(
            &npy_path,
            format!("shape {:?}, expected (N, 17) with N > 0", arr.shape),
        ));
    }
    if arr.data.iter().any(|v| !v.is_finite()) {
        return Err(DataError::npy(&npy_path, "contains NaN or infinite values"));
    }
    let n = arr.shape[0];
    let (img_dir, extra) = image_folder(dir, opts.downscale.max(1))?;
    let files = list_images(&img_dir)?;
    if files.len() != n {
        return Err(DataError::invalid(
            &img_dir,
            format!(
                "{} images but {} has {n} rows: counts do not match",
                files.len(),
                npy_path.display()
            ),
        ));
    }
    let images = parallel_map(&files, |p| {
        let (img, _) = read_image(p)?.composite_on_white();
        Ok(if extra > 1 {
            img.downscaled(extra)
        } else {
            img
        })
    })?;
    let (w, h) = (images[0].width, images[0].height);
    for (img, p) in images.iter().zip(&files) {
        if (img.width, img.height) != (w, h) {
            return Err(DataError::invalid(
                p,
                format!(
                    "image is {}×{} but {} is {w}×{h}: mixed image sizes",
                    img.width,
                    img.height,
                    files[0].display()
                ),
            ));
        }
    }

    // Poses in f64: reorder [down, right, back] → [right, up, back].
    let mut poses: Vec<[[f64; 4]; 3]> = Vec::with_capacity(n);
    let mut hwf = Vec::with_capacity(n);
    let mut bds = Vec::with_capacity(n);
    for i in 0..n {
        let m = |r: usize, c: usize| arr.at2(i, r * 5 + c);
        let mut p = [[0.0; 4]; 3];
        for (r, row) in p.iter_mut().enumerate() {
            *row = [m(r, 1), -m(r, 0), m(r, 2), m(r, 3)];
        }
        poses.push(p);
        hwf.push((m(0, 4), m(1, 4), m(2, 4)));
        bds.push((arr.at2(i, 15), arr.at2(i, 16)));
    }
    for (i, &(hh, ww, f)) in hwf.iter().enumerate() {
        if !(hh > 0.0 && ww > 0.0 && f > 0.0) {
            return Err(DataError::npy(
                &npy_path,
                format!("row {i}: H, W, focal = {hh}, {ww}, {f} must be positive"),
            ));
        }
    }
    let min_bd = bds.iter().map(|b| b.0).fold(f64::INFINITY, f64::min);
    let max_bd = bds.iter().map(|b| b.1).fold(f64::NEG_INFINITY, f64::max);
    // All values are finite (checked above), so plain comparisons suffice.
    if min_bd <= 0.0 || max_bd < min_bd {
        return Err(DataError::npy(
            &npy_path,
            format!("depth bounds [{min_bd}, {max_bd}] are not positive and ordered"),
        ));
    }
    let (framing, sc) = forward_facing(&poses, &bds, opts.bd_factor as f64);
    let mut views = Vec::with_capacity(n);
    for (i, (image, path)) in images.into_iter().zip(files).enumerate() {
        let (h0, w0, f0) = hwf[i];
        let camera = Camera::new(
            w,
            h,
            (f0 * w as f64 / w0) as f32,
            (f0 * h as f64 / h0) as f32,
            0.5 * w as f32,
            0.5 * h as f32,
            framing.poses[i],
        );
        let depth_range = framing.depth_ranges[i];
        views.push(View {
            camera,
            image,
            mask: None,
            path,
            mask_path: None,
            depth_range,
        });
    }
    let hold = opts.llff_hold;
    let test: Vec<usize> = if hold > 0 {
        (0..n).step_by(hold).collect()
    } else {
        Vec::new()
    };
    let train: Vec<usize> = (0..n).filter(|i| !test.contains(i)).collect();
    let bounds = frustum_bounds(&views);
    Ok(Scene {
        name: super::folder_name(dir),
        format: SceneFormat::Llff,
        root: dir.to_path_buf(),
        views,
        val: test.clone(),
        test,
        train,
        near: (min_bd * sc * 0.9) as f32,
        far: (max_bd * sc) as f32,
        bounds,
        per_ray_range: false,
        to_scene: framing.to_scene,
        white_background: false,
        forward_facing: true,
        contraction: None,
        points: Vec::new(),
        notes: Vec::new(),
    })
}

/// The image folder to read and the extra in-memory downscale: `images_N/` when it exists, else
/// `images/` downscaled by N; with N = 1 and no `images/`, the smallest `images_K/` there is.
fn image_folder(dir: &Path, factor: u32) -> Result<(PathBuf, u32), DataError> {
    let full = dir.join("images");
    if factor > 1 {
        let exact = dir.join(format!("images_{factor}"));
        if exact.is_dir() {
            return Ok((exact, 1));
        }
        if full.is_dir() {
            return Ok((full, factor));
        }
        return Err(DataError::missing(
            &exact,
            format!("image folder (and no {} to downscale)", full.display()),
        ));
    }
    if full.is_dir() {
        return Ok((full, 1));
    }
    let mut best: Option<(u32, PathBuf)> = None;
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            if let Some(k) = name
                .strip_prefix("images_")
                .and_then(|k| k.parse::<u32>().ok())
                && e.path().is_dir()
                && best.as_ref().is_none_or(|b| k < b.0)
            {
                best = Some((k, e.path()));
            }
        }
    }
    best.map(|(_, p)| (p, 1))
        .ok_or_else(|| DataError::missing(&full, "image folder (images/ or images_N/)"))
}
