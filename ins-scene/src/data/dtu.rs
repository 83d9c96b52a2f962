//! DTU scenes in the IDR / NeuS layout: `cameras.npz` or `cameras_sphere.npz` with
//! `world_mat_i` (projection, 4×4 or 3×4) and `scale_mat_i` (unit sphere → world), images in
//! `image/` or `images/`, object masks (0/255) in `mask/`, paired with the images by sorted order.
//!
//! `P = (world_mat_i · scale_mat_i)[:3]` maps unit-sphere coordinates to pixels; it is split by
//! an RQ decomposition into intrinsics `K` (positive diagonal, `K[2][2] = 1`) and the pose,
//! which is converted from OpenCV to OpenGL axes (and pixel-centre conventions: see
//! [`Decomposed::camera`]). The scene frame is the unit-sphere frame; every
//! view trains (IDR/NeuS use all views), val and test are empty.

use std::collections::BTreeMap;
use std::path::Path;

use super::DataError;
use super::images::{list_images, parallel_map, read_image, read_mask};
use super::npy::{Array, read_npz};
use super::scene::{LoadOptions, Scene, SceneFormat, View};
use crate::camera::Camera;
use crate::geometry::{Bounds, Similarity, inverse3_f64};

/// Intrinsics and pose recovered from a 3×4 projection matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decomposed {
    /// Upper-triangular intrinsics with positive diagonal and `k[2][2] = 1`.
    pub k: [[f64; 3]; 3],
    /// World-to-camera rotation, OpenCV axes (x right, y down, z forward), `det = +1`.
    pub r: [[f64; 3]; 3],
    /// Camera centre in world coordinates.
    pub center: [f64; 3],
}

/// Splits `P = λ·K·[R | −R·C]` (any non-zero scale λ, either sign) into `K`, `R` and `C` by
/// an RQ decomposition (Gram–Schmidt from the last row up). `None` when `P[:, :3]` is singular.
pub fn decompose_projection(p: &[[f64; 4]; 3]) -> Option<Decomposed> {
    let mut m = [
        [p[0][0], p[0][1], p[0][2]],
        [p[1][0], p[1][1], p[1][2]],
        [p[2][0], p[2][1], p[2][2]],
    ];
    let mut p4 = [p[0][3], p[1][3], p[2][3]];
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if !det.is_finite() || det == 0.0 {
        return None;
    }
    if det < 0.0 {
        // P is homogeneous: −P projects the same, and makes det(K·R) > 0 so R is a rotation.
        m = m.map(|r| r.map(|v| -v));
        p4 = p4.map(|v| -v);
    }
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let axpy =
        |a: [f64; 3], s: f64, b: [f64; 3]| [a[0] - s * b[0], a[1] - s * b[1], a[2] - s * b[2]];
    let k22 = dot(m[2], m[2]).sqrt();
    let r2 = m[2].map(|v| v / k22);
    let k12 = dot(m[1], r2);
    let u1 = axpy(m[1], k12, r2);
    let k11 = dot(u1, u1).sqrt();
    let r1 = u1.map(|v| v / k11);
    let k02 = dot(m[0], r2);
    let k01 = dot(m[0], r1);
    let u0 = axpy(axpy(m[0], k02, r2), k01, r1);
    let k00 = dot(u0, u0).sqrt();
    let r0 = u0.map(|v| v / k00);
    if !(k00 > 0.0 && k11 > 0.0 && k22 > 0.0) {
        return None;
    }
    let k = [
        [k00 / k22, k01 / k22, k02 / k22],
        [0.0, k11 / k22, k12 / k22],
        [0.0, 0.0, 1.0],
    ];
    let minv = inverse3_f64(&m)?;
    let center = [0, 1, 2].map(|r| -(minv[r][0] * p4[0] + minv[r][1] * p4[1] + minv[r][2] * p4[2]));
    Some(Decomposed {
        k,
        r: [r0, r1, r2],
        center,
    })
}

impl Decomposed {
    /// The camera for an image of `width`×`height`, in our OpenGL convention. OpenCV
    /// intrinsics put pixel centres at integer coordinates (IDR and NeuS cast the ray of pixel
    /// `(u, v)` through `K⁻¹·[u, v, 1]`); ours put them at `+0.5`, so `cx` and `cy` shift by half a
    /// pixel and the ray of each pixel stays the same.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        let r = &self.r;
        // c2w rotation (OpenCV) = Rᵀ; OpenGL flips the y and z columns.
        let mut c2w = [[0.0f32; 4]; 3];
        for row in 0..3 {
            c2w[row] = [
                r[0][row] as f32,
                -r[1][row] as f32,
                -r[2][row] as f32,
                self.center[row] as f32,
            ];
        }
        let k = &self.k;
        Camera {
            width,
            height,
            fx: k[0][0] as f32,
            fy: k[1][1] as f32,
            cx: (k[0][2] + 0.5) as f32,
            cy: (k[1][2] + 0.5) as f32,
            skew: k[0][1] as f32,
            c2w,
            distortion: Default::default(),
        }
    }
}

/// Reads a DTU (IDR/NeuS layout) scene from `dir`.
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let cam_path = ["cameras_sphere.npz", "cameras.npz"]
        .iter()
        .map(|f| dir.join(f))
        .find(|p| p.is_file())
        .ok_or_else(|| {
            DataError::missing(
                &dir.join("cameras.npz"),
                "DTU cameras (cameras.npz or cameras_sphere.npz)",
            )
        })?;
    let img_dir = ["image", "images"]
        .iter()
        .map(|f| dir.join(f))
        .find(|p| p.is_dir())
        .ok_or_else(|| {
            DataError::missing(&dir.join("image"), "image folder (image/ or images/)")
        })?;
    let files = list_images(&img_dir)?;
    if files.is_empty() {
        return Err(DataError::invalid(&img_dir, "no images"));
    }
    let mask_dir = dir.join("mask");
    let mask_files = if mask_dir.is_dir() {
        Some(list_images(&mask_dir)?)
    } else {
        None
    };
    if let Some(masks) = &mask_files {
        if masks.len() > files.len() {
            return Err(DataError::invalid(
                &masks[files.len()],
                format!(
                    "mask without an image: {} masks but {} images in {}",
                    masks.len(),
                    files.len(),
                    img_dir.display()
                ),
            ));
        }
        if masks.len() < files.len() {
            return Err(DataError::invalid(
                &files[masks.len()],
                format!(
                    "image without a mask: {} images but {} masks in {}",
                    files.len(),
                    masks.len(),
                    mask_dir.display()
                ),
            ));
        }
    }

    let npz = read_npz(&cam_path)?;
    let n_world = npz
        .keys()
        .filter(|k| k.starts_with("world_mat_") && !k.starts_with("world_mat_inv"))
        .count();
    if n_world != files.len() {
        return Err(DataError::invalid(
            &cam_path,
            format!(
                "{n_world} world_mat_* entries but {} images in {}: counts do not match",
                files.len(),
                img_dir.display()
            ),
        ));
    }
    let mut decomposed = Vec::with_capacity(files.len());
    let mut first_scale = None;
    for i in 0..files.len() {
        let world = matrix(&npz, &cam_path, &format!("world_mat_{i}"))?;
        let scale = matrix(&npz, &cam_path, &format!("scale_mat_{i}"))?;
        if first_scale.is_none() {
            first_scale = Some(scale);
        }
        let mut p = [[0.0; 4]; 3];
        for r in 0..3 {
            for c in 0..4 {
                p[r][c] = (0..4).map(|k| world[r][k] * scale[k][c]).sum();
            }
        }
        let d = decompose_projection(&p).ok_or_else(|| {
            DataError::invalid(
                &cam_path,
                format!("world_mat_{i} · scale_mat_{i} is not a valid projection"),
            )
        })?;
        decomposed.push(d);
    }
    let scale0 = first_scale.ok_or_else(|| DataError::invalid(&cam_path, "no cameras"))?;
    let to_scene = similarity_inverse(&scale0).ok_or_else(|| {
        DataError::invalid(
            &cam_path,
            "scale_mat_0 is not a uniform scale, rotation and translation",
        )
    })?;

    let factor = opts.downscale.max(1);
    let images = parallel_map(&files, |p| {
        let (img, _) = read_image(p)?.composite_on_white();
        Ok(if factor > 1 {
            img.downscaled(factor)
        } else {
            img
        })
    })?;
    let masks = match &mask_files {
        Some(m) => Some(parallel_map(m, |p| {
            let mask = read_mask(p)?;
            Ok(if factor > 1 {
                mask.downscaled(factor)
            } else {
                mask
            })
        })?),
        None => None,
    };
    let (w, h) = (images[0].width, images[0].height);
    let mut views = Vec::with_capacity(files.len());
    let mut masks_iter = masks.map(|m| m.into_iter());
    for (i, (image, path)) in images.into_iter().zip(files.iter()).enumerate() {
        if (image.width, image.height) != (w, h) {
            return Err(DataError::invalid(
                path,
                format!(
                    "image is {}×{} but {} is {w}×{h}: mixed image sizes",
                    image.width,
                    image.height,
                    files[0].display()
                ),
            ));
        }
        let (mask, mask_path) = match (&mut masks_iter, &mask_files) {
            (Some(it), Some(mf)) => {
                let m = it
                    .next()
                    .ok_or_else(|| DataError::invalid(&mask_dir, "fewer masks than images"))?;
                if (m.width, m.height) != (w, h) {
                    return Err(DataError::invalid(
                        &mf[i],
                        format!(
                            "mask is {}×{} but its image {} is {w}×{h}",
                            m.width,
                            m.height,
                            path.display()
                        ),
                    ));
                }
                (Some(m), Some(mf[i].clone()))
            }
            _ => (None, None),
        };
        let full = decomposed[i].camera(w * factor, h * factor);
        let camera = if factor > 1 {
            full.downscaled(factor)
        } else {
            full
        };
        views.push(View {
            camera,
            image,
            mask,
            path: path.clone(),
            mask_path,
            depth_range: None,
        });
    }
    let dists: Vec<f32> = views.iter().map(|v| v.camera.origin().length()).collect();
    let near = dists.iter().fold(f32::INFINITY, |a, &d| a.min(d)) - 1.0;
    let far = dists.iter().fold(0.0f32, |a, &d| a.max(d)) + 1.0;
    Ok(Scene {
        name: super::folder_name(dir),
        format: SceneFormat::Dtu,
        root: dir.to_path_buf(),
        train: (0..views.len()).collect(),
        val: Vec::new(),
        test: Vec::new(),
        views,
        near: near.max(0.0),
        far,
        bounds: Bounds::Sphere {
            center: crate::geometry::Vec3::ZERO,
            radius: 1.0,
        },
        per_ray_range: true,
        to_scene,
        white_background: false,
        forward_facing: false,
        contraction: None,
        points: Vec::new(),
        notes: Vec::new(),
    })
}

/// A 4×4 (or 3×4, completed with `[0, 0, 0, 1]`) matrix from the archive.
fn matrix(
    npz: &BTreeMap<String, Array>,
    path: &Path,
    name: &str,
) -> Result<[[f64; 4]; 4], DataError> {
    let a = npz
        .get(name)
        .ok_or_else(|| DataError::invalid(path, format!("{name} missing")))?;
    if a.shape.len() != 2 || a.shape[1] != 4 || !(a.shape[0] == 3 || a.shape[0] == 4) {
        return Err(DataError::npy(
            path,
            format!("{name} has shape {:?}, expected (4, 4) or (3, 4)", a.shape),
        ));
    }
    if a.data.iter().any(|v| !v.is_finite()) {
        return Err(DataError::npy(
            path,
            format!("{name} contains NaN or infinite values"),
        ));
    }
    let mut m = [
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    for (r, row) in m.iter_mut().enumerate().take(a.shape[0]) {
        for (c, v) in row.iter_mut().enumerate() {
            *v = a.at2(r, c);
        }
    }
    Ok(m)
}

/// The similarity `scale_mat⁻¹` (world → unit sphere), when `scale_mat` is one.
fn similarity_inverse(s: &[[f64; 4]; 4]) -> Option<Similarity> {
    let a = [
        [s[0][0], s[0][1], s[0][2]],
        [s[1][0], s[1][1], s[1][2]],
        [s[2][0], s[2][1], s[2][2]],
    ];
    let inv = inverse3_f64(&a)?;
    let t = [s[0][3], s[1][3], s[2][3]];
    let mut m = [[0.0; 4]; 3];
    for r in 0..3 {
        m[r] = [
            inv[r][0],
            inv[r][1],
            inv[r][2],
            -(inv[r][0] * t[0] + inv[r][1] * t[1] + inv[r][2] * t[2]),
        ];
    }
    Similarity::from_affine(&m)
}
