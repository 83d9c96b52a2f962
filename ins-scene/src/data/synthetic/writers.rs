//! Writing an analytic scene out in the Blender, LLFF and DTU/IDR formats, with the ground truth
//! a test checks the loaders against.

use std::path::{Path, PathBuf};

use serde_json::json;

use super::analytic::{AnalyticScene, Rendering};
use crate::camera::{Camera, flip_yz, pose_look_at};
use crate::data::DataError;
use crate::data::images::{to_u8, write_png};
use crate::data::npy::{write_npy, write_npz};
use crate::data::scene::{SceneFormat, Split};
use crate::geometry::{Mat3, Similarity, Vec3, mat3_rows};

/// Size and count of a generated scene.
#[derive(Clone, Copy, Debug)]
pub struct SynthOptions {
    /// Image width in pixels (height is the same for Blender, 3/4 of it for LLFF and DTU).
    pub size: u32,
    /// Number of views (Blender: training views; val and test get `max(1, views/4)` each).
    pub views: usize,
}

impl Default for SynthOptions {
    fn default() -> Self {
        SynthOptions {
            size: 64,
            views: 10,
        }
    }
}

/// The ground truth of one written view.
#[derive(Clone, Debug)]
pub struct SynthView {
    /// Camera in the written world frame (our OpenGL convention).
    pub camera: Camera,
    /// Split it was written to (Blender); LLFF and DTU write [`Split::Train`] here and leave
    /// the holdout to the loader.
    pub split: Split,
    /// The image file written.
    pub image_path: PathBuf,
    /// Its exact rendering.
    pub render: Rendering,
    /// Smallest and largest z-depth over the pixels that hit something.
    pub depth_bounds: (f32, f32),
}

impl SynthView {
    /// The view of `camera`, with the depth bounds of its rendering.
    pub(crate) fn new(
        camera: Camera,
        split: Split,
        image_path: PathBuf,
        render: Rendering,
    ) -> Self {
        let depth_bounds = z_depth_bounds(&camera, &render);
        SynthView {
            camera,
            split,
            image_path,
            render,
            depth_bounds,
        }
    }
}

/// Everything a test needs to check a written scene: the analytic scene in the written world
/// frame and each view's camera and rendering, in the order the loader will list them.
#[derive(Clone, Debug)]
pub struct SynthScene {
    /// Format written.
    pub format: SceneFormat,
    /// Folder written.
    pub dir: PathBuf,
    /// The analytic scene (its `to_world` maps into the written world frame).
    pub scene: AnalyticScene,
    /// The views, in loader order.
    pub views: Vec<SynthView>,
}

/// Writes a small analytic scene in `format` into `dir` (created if needed); captures
/// (COLMAP, transforms.json) are object-centred, COLMAP's binary.
pub fn write(
    format: SceneFormat,
    dir: &Path,
    opts: &SynthOptions,
) -> Result<SynthScene, DataError> {
    match format {
        SceneFormat::Blender => write_blender(dir, opts),
        SceneFormat::Llff => write_llff(dir, opts),
        SceneFormat::Dtu => write_dtu(dir, opts),
        SceneFormat::Colmap => super::write_colmap(
            dir,
            opts,
            super::CaptureLayout::ObjectCentred,
            crate::data::colmap_model::Encoding::Binary,
        ),
        SceneFormat::Transforms => {
            super::write_transforms(dir, opts, super::CaptureLayout::ObjectCentred)
        }
    }
}

fn create_dir(dir: &Path) -> Result<(), DataError> {
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))
}

fn z_depth_bounds(camera: &Camera, r: &Rendering) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
    for v in 0..r.height {
        for u in 0..r.width {
            let t = r.depth[(v * r.width + u) as usize];
            if t.is_finite() {
                let (o, d) = camera.pixel_ray(u, v);
                if let Some(z) = camera.depth_of(o + d * t) {
                    lo = lo.min(z);
                    hi = hi.max(z);
                }
            }
        }
    }
    (lo, hi)
}

/// Rotation by `angle` radians about `axis`.
fn axis_angle(axis: Vec3, angle: f32) -> Mat3 {
    Mat3::from_axis_angle(axis.normalize(), angle)
}

/// NeRF-synthetic: cameras on a sphere of radius 4 around the origin (z up), looking at it,
/// `camera_angle_x` 0.6911 (the lego value), RGBA images with alpha 0 on the background.
pub fn write_blender(dir: &Path, opts: &SynthOptions) -> Result<SynthScene, DataError> {
    let scene = AnalyticScene::tabletop(false);
    let size = opts.size.max(8);
    let fov = 0.691_111_2f32;
    let n_other = (opts.views / 4).max(1);
    let mut views = Vec::new();
    for (split, count, phase) in [
        (Split::Train, opts.views.max(1), 0.0f32),
        (Split::Val, n_other, 0.37),
        (Split::Test, n_other, 0.71),
    ] {
        let sub_dir = dir.join(split.to_string());
        create_dir(&sub_dir)?;
        let mut frames = Vec::new();
        for i in 0..count {
            let az = (i as f32 + phase) * 2.399_963 + phase;
            let el = (10.0 + 50.0 * ((i as f32 + 0.5 + phase) / count as f32).fract()).to_radians();
            let eye = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * 4.0;
            let camera = Camera::from_fov_x(
                size,
                size,
                fov,
                pose_look_at(eye, Vec3::ZERO, Vec3::new(0.0, 0.0, 1.0)),
            );
            let render = scene.render(&camera);
            let mut rgba = Vec::with_capacity((size * size * 4) as usize);
            for (k, &m) in render.mask.iter().enumerate() {
                if m {
                    rgba.extend(render.rgb[k * 3..k * 3 + 3].iter().map(|&v| to_u8(v)));
                    rgba.push(255);
                } else {
                    rgba.extend([0, 0, 0, 0]);
                }
            }
            let image_path = sub_dir.join(format!("r_{i}.png"));
            write_png(&image_path, size, size, 4, &rgba)?;
            let c = &camera.c2w;
            frames.push(json!({
                "file_path": format!("./{split}/r_{i}"),
                "rotation": 0.0,
                "transform_matrix": [c[0], c[1], c[2], [0.0, 0.0, 0.0, 1.0]],
            }));
            views.push(SynthView::new(camera, split, image_path, render));
        }
        let path = dir.join(format!("transforms_{split}.json"));
        let text =
            serde_json::to_string_pretty(&json!({ "camera_angle_x": fov, "frames": frames }))
                .map_err(|e| DataError::json(&path, e.to_string()))?;
        std::fs::write(&path, text).map_err(|e| DataError::io(&path, e))?;
    }
    write_reference_surface(&scene, &views, dir)?;
    Ok(SynthScene {
        format: SceneFormat::Blender,
        dir: dir.to_path_buf(),
        scene,
        views,
    })
}

/// LLFF: a grid of roughly parallel cameras looking down local −z at [`AnalyticScene::forward_facing`],
/// all placed in a world frame rotated, scaled (×2.5) and shifted from the local one, written as
/// `poses_bounds.npy` ([down, right, back] columns, H, W, focal, then the z-depth range each
/// view sees) and `images/imageNNN.png`.
pub fn write_llff(dir: &Path, opts: &SynthOptions) -> Result<SynthScene, DataError> {
    let mut scene = AnalyticScene::forward_facing();
    scene.to_world = Similarity {
        scale: 2.5,
        rotation: axis_angle(Vec3::new(0.3, 1.0, 0.2), 0.5),
        translation: Vec3::new(3.0, -1.0, 2.0),
    };
    let w = opts.size.max(8);
    let h = (w * 3 / 4).max(6);
    let focal = 0.9 * w as f32;
    let img_dir = dir.join("images");
    create_dir(&img_dir)?;
    let n = opts.views.max(1);
    let cols = (n as f32).sqrt().ceil() as usize;
    let mut views = Vec::new();
    let mut rows = Vec::with_capacity(n * 17);
    for i in 0..n {
        let (gx, gy) = ((i % cols) as f32, (i / cols) as f32);
        let eye_l = Vec3::new(
            0.25 * gx - 0.125 * (cols as f32 - 1.0),
            0.2 * gy - 0.1 * ((n / cols) as f32),
            0.03 * (i % 3) as f32,
        );
        let target_l = Vec3::new(0.05 * (i % 2) as f32, 0.0, -5.0);
        let pose_l = pose_look_at(eye_l, target_l, Vec3::new(0.0, 1.0, 0.0));
        let s = &scene.to_world;
        let rot_l = crate::geometry::mat3_from_rows(pose_l.map(|r| [r[0], r[1], r[2]]));
        let rot_w = mat3_rows(s.rotation * rot_l);
        let eye_w = s.apply_point(eye_l);
        let c2w: [[f32; 4]; 3] =
            std::array::from_fn(|r| [rot_w[r][0], rot_w[r][1], rot_w[r][2], eye_w[r]]);
        let camera = Camera::new(w, h, focal, focal, 0.5 * w as f32, 0.5 * h as f32, c2w);
        let render = scene.render(&camera);
        let image_path = img_dir.join(format!("image{i:03}.png"));
        let rgb: Vec<u8> = render.rgb.iter().map(|&v| to_u8(v)).collect();
        write_png(&image_path, w, h, 3, &rgb)?;
        let view = SynthView::new(camera, Split::Train, image_path, render);
        let depth_bounds = view.depth_bounds;
        // LLFF columns: [down, right, back, t, hwf] = [−up, right, back, t, hwf].
        for r in 0..3 {
            let hwf = [h as f32, w as f32, focal][r];
            rows.extend([-c2w[r][1], c2w[r][0], c2w[r][2], c2w[r][3], hwf].map(f64::from));
        }
        rows.extend([depth_bounds.0 as f64, depth_bounds.1 as f64]);
        views.push(view);
    }
    write_npy(&dir.join("poses_bounds.npy"), &[n, 17], &rows)?;
    Ok(SynthScene {
        format: SceneFormat::Llff,
        dir: dir.to_path_buf(),
        scene,
        views,
    })
}

/// The file [`write_dtu_of`] and [`write_blender`] write the true surface to (world frame),
/// for `eval mesh`.
pub const REFERENCE_SURFACE: &str = "reference.ply";

/// Spacing (local units, the unit sphere's) of the reference surface's points: a 400-pixel
/// view of the unit sphere spends about 0.005 a pixel, so this is about two pixels.
const REFERENCE_SPACING: f32 = 0.01;

/// Writes the part of `scene`'s foreground surface that `views` see as a PLY point cloud in
/// the world frame ([`REFERENCE_SURFACE`]).
fn write_reference_surface(
    scene: &AnalyticScene,
    views: &[SynthView],
    dir: &Path,
) -> Result<(), DataError> {
    let world: Vec<Vec3> = scene
        .foreground_surface(REFERENCE_SPACING)
        .into_iter()
        .map(|p| scene.to_world.apply_point(p))
        .collect();
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let seen: Vec<glam::DVec3> = scene
        .seen_by(&world, &cameras)
        .into_iter()
        .map(|p| p.as_dvec3())
        .collect();
    crate::data::ply_points::write_ply_points(&dir.join(REFERENCE_SURFACE), &seen)
}

/// DTU / IDR: [`AnalyticScene::tabletop`] (unit-sphere frame, objects foreground, ground not)
/// placed by `scale_mat` (×30, shifted) in a world frame; cameras 2.6 units from the centre on
/// an arc above the table, with skewed, off-centre intrinsics; `world_mat_i = 1.7 · K·[R | t]`
/// (OpenCV axes, an arbitrary homogeneous scale), `image/NNNNNN.png`, `mask/NNN.png` (0/255 RGB).
pub fn write_dtu(dir: &Path, opts: &SynthOptions) -> Result<SynthScene, DataError> {
    write_dtu_of(AnalyticScene::tabletop(true), dir, opts)
}

/// [`write_dtu`] of another analytic scene (its local frame is the unit sphere's).
pub fn write_dtu_of(
    mut scene: AnalyticScene,
    dir: &Path,
    opts: &SynthOptions,
) -> Result<SynthScene, DataError> {
    let world_scale = 30.0f32;
    let shift = [12.0f32, -3.0, 40.0];
    scene.to_world = Similarity {
        scale: world_scale,
        rotation: Similarity::identity().rotation,
        translation: Vec3::from(shift),
    };
    let w = opts.size.max(8);
    let h = (w * 3 / 4).max(6);
    let (fx, fy, cx, cy, skew) = (
        1.1 * w as f32,
        1.12 * w as f32,
        0.5 * w as f32 + 1.5,
        0.5 * h as f32 - 1.0,
        0.3f32,
    );
    let img_dir = dir.join("image");
    let mask_dir = dir.join("mask");
    create_dir(&img_dir)?;
    create_dir(&mask_dir)?;
    let n = opts.views.max(1);
    let lambda = 1.7f64;
    let mut arrays = Vec::new();
    let mut views = Vec::new();
    for i in 0..n {
        let az = (-60.0 + 150.0 * i as f32 / n as f32).to_radians();
        let el = (25.0 + 20.0 * (i % 3) as f32).to_radians();
        let eye_l = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * 2.6;
        let pose_l = pose_look_at(eye_l, Vec3::new(0.0, 0.0, -0.1), Vec3::new(0.0, 0.0, 1.0));
        let eye_w = scene.to_world.apply_point(eye_l);
        let c2w: [[f32; 4]; 3] =
            std::array::from_fn(|r| [pose_l[r][0], pose_l[r][1], pose_l[r][2], eye_w[r]]);
        let camera = Camera {
            width: w,
            height: h,
            fx,
            fy,
            cx,
            cy,
            skew,
            c2w,
            distortion: Default::default(),
        };
        let render = scene.render(&camera);
        let image_path = img_dir.join(format!("{i:06}.png"));
        let rgb: Vec<u8> = render.rgb.iter().map(|&v| to_u8(v)).collect();
        write_png(&image_path, w, h, 3, &rgb)?;
        let mask: Vec<u8> = render
            .mask
            .iter()
            .flat_map(|&m| [if m { 255 } else { 0 }; 3])
            .collect();
        write_png(&mask_dir.join(format!("{i:03}.png")), w, h, 3, &mask)?;
        // OpenCV world-to-camera: R = (c2w · diag(1, −1, −1))ᵀ, t = −R·C.
        let cv = flip_yz(&c2w);
        let r: [[f64; 3]; 3] = std::array::from_fn(|a| std::array::from_fn(|b| cv[b][a] as f64));
        let cc = [eye_w[0] as f64, eye_w[1] as f64, eye_w[2] as f64];
        let t: [f64; 3] =
            std::array::from_fn(|a| -(r[a][0] * cc[0] + r[a][1] * cc[1] + r[a][2] * cc[2]));
        // OpenCV pixel centres are at integers, ours at +0.5.
        let k = [
            [fx as f64, skew as f64, cx as f64 - 0.5],
            [0.0, fy as f64, cy as f64 - 0.5],
            [0.0, 0.0, 1.0],
        ];
        let mut world = vec![0.0f64; 16];
        for a in 0..3 {
            for b in 0..4 {
                let rt = |m: usize| if b < 3 { r[m][b] } else { t[m] };
                world[a * 4 + b] = lambda * (0..3).map(|m| k[a][m] * rt(m)).sum::<f64>();
            }
        }
        world[15] = 1.0;
        let s = world_scale as f64;
        let scale_mat = vec![
            s,
            0.0,
            0.0,
            shift[0] as f64,
            0.0,
            s,
            0.0,
            shift[1] as f64,
            0.0,
            0.0,
            s,
            shift[2] as f64,
            0.0,
            0.0,
            0.0,
            1.0,
        ];
        arrays.push((format!("world_mat_{i}"), vec![4, 4], world));
        arrays.push((format!("scale_mat_{i}"), vec![4, 4], scale_mat));
        views.push(SynthView::new(camera, Split::Train, image_path, render));
    }
    write_npz(&dir.join("cameras.npz"), &arrays)?;
    write_reference_surface(&scene, &views, dir)?;
    Ok(SynthScene {
        format: SceneFormat::Dtu,
        dir: dir.to_path_buf(),
        scene,
        views,
    })
}
