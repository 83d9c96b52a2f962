//! Writing an analytic scene as a user's capture would arrive: a COLMAP workspace (binary or
//! text model, with sparse points and their observations) or an instant-ngp / nerfstudio
//! `transforms.json`, taken through a lens with OpenCV distortion, in a world frame of its own
//! (rotated, scaled, shifted), so the readers' conventions and the framing are both exercised.
//! Object-centred captures come with the objects' masks in `masks/` (COLMAP's naming,
//! `NAME.png`; transforms.json's `mask_path`), as a capture prepared for a surface method has.

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::json;

use super::analytic::AnalyticScene;
use super::writers::{SynthOptions, SynthScene, SynthView};
use crate::camera::{Camera, flip_yz, pose_look_at};
use crate::data::DataError;
use crate::data::colmap_model::{
    CameraModel, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, Encoding, write_model,
};
use crate::data::images::{to_u8, write_png};
use crate::data::ply_points::write_ply_points;
use crate::data::scene::{SceneFormat, Split};
use crate::distortion::Distortion;
use crate::geometry::{Mat3, Similarity, Vec3, mat3_rows};

/// How the synthetic capture's cameras are placed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureLayout {
    /// Around a tabletop in a room ([`AnalyticScene::room`]: floor and walls well past the
    /// cameras), at varying heights.
    ObjectCentred,
    /// Around the tabletop's objects before a plain backdrop ([`AnalyticScene::studio`]):
    /// sparse points on the objects alone.
    Studio,
    /// A hand-held grid of cameras looking one way (the LLFF layout).
    ForwardFacing,
}

impl CaptureLayout {
    /// Whether the cameras surround the objects (and the capture has their masks).
    pub fn object_centred(self) -> bool {
        self != CaptureLayout::ForwardFacing
    }
}

/// The lens of the synthetic captures: a mild barrel with tangential terms, like a phone's.
pub const SYNTH_LENS: Distortion = Distortion::Polynomial {
    k: [-0.08, 0.02, 0.0, 0.0, 0.0, 0.0],
    p: [1.5e-3, -1e-3],
};

/// Cameras of a capture in the written world frame, with the analytic scene placed there.
fn capture_cameras(layout: CaptureLayout, opts: &SynthOptions) -> (AnalyticScene, Vec<Camera>) {
    let w = opts.size.max(8);
    let h = (w * 3 / 4).max(6);
    let (fx, fy) = (0.95 * w as f32, 0.97 * w as f32);
    let (cx, cy) = (0.5 * w as f32 + 0.7, 0.5 * h as f32 - 0.4);
    let n = opts.views.max(1);
    let (mut scene, local): (AnalyticScene, Vec<[[f32; 4]; 3]>) = match layout {
        CaptureLayout::ObjectCentred | CaptureLayout::Studio => (
            if layout == CaptureLayout::Studio {
                AnalyticScene::studio()
            } else {
                AnalyticScene::room()
            },
            (0..n)
                .map(|i| {
                    let az = i as f32 / n as f32 * std::f32::consts::TAU;
                    let el = (20.0 + 15.0 * (i % 3) as f32).to_radians();
                    let eye = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * 3.0;
                    pose_look_at(eye, Vec3::new(0.0, 0.0, -0.1), Vec3::Z)
                })
                .collect(),
        ),
        CaptureLayout::ForwardFacing => {
            let cols = (n as f32).sqrt().ceil() as usize;
            (
                AnalyticScene::forward_facing(),
                (0..n)
                    .map(|i| {
                        let (gx, gy) = ((i % cols) as f32, (i / cols) as f32);
                        let eye = Vec3::new(0.25 * gx - 0.125 * cols as f32, 0.2 * gy, 0.0);
                        pose_look_at(eye, Vec3::new(0.05 * (i % 2) as f32, 0.0, -5.0), Vec3::Y)
                    })
                    .collect(),
            )
        }
    };
    scene.to_world = Similarity {
        scale: 1.7,
        rotation: Mat3::from_axis_angle(Vec3::new(0.2, -0.4, 1.0).normalize(), 0.9),
        translation: Vec3::new(-2.0, 5.0, 1.5),
    };
    let s = scene.to_world;
    let cameras = local
        .into_iter()
        .map(|p| {
            let rot = mat3_rows(
                s.rotation * crate::geometry::mat3_from_rows(p.map(|r| [r[0], r[1], r[2]])),
            );
            let eye = s.apply_point(Vec3::new(p[0][3], p[1][3], p[2][3]));
            let c2w = std::array::from_fn(|r| [rot[r][0], rot[r][1], rot[r][2], eye[r]]);
            Camera::new(w, h, fx, fy, cx, cy, c2w).with_distortion(SYNTH_LENS)
        })
        .collect();
    (scene, cameras)
}

/// Renders and writes `images/NAME` for each camera and, with `mask_name`, the foreground
/// mask as `masks/MASK_NAME`.
fn render_views(
    scene: &AnalyticScene,
    cameras: Vec<Camera>,
    dir: &Path,
    name: impl Fn(usize) -> String,
    mask_name: Option<fn(&str) -> String>,
) -> Result<Vec<SynthView>, DataError> {
    let img_dir = dir.join("images");
    std::fs::create_dir_all(&img_dir).map_err(|e| DataError::io(&img_dir, e))?;
    let mask_dir = dir.join("masks");
    if mask_name.is_some() {
        std::fs::create_dir_all(&mask_dir).map_err(|e| DataError::io(&mask_dir, e))?;
    }
    cameras
        .into_iter()
        .enumerate()
        .map(|(i, camera)| {
            let render = scene.render(&camera);
            let file = name(i);
            let path = img_dir.join(&file);
            let rgb: Vec<u8> = render.rgb.iter().map(|&v| to_u8(v)).collect();
            write_png(&path, camera.width, camera.height, 3, &rgb)?;
            if let Some(mask_name) = mask_name {
                let m: Vec<u8> = render
                    .mask
                    .iter()
                    .map(|&b| if b { 255 } else { 0 })
                    .collect();
                write_png(
                    &mask_dir.join(mask_name(&file)),
                    camera.width,
                    camera.height,
                    1,
                    &m,
                )?;
            }
            Ok(SynthView::new(camera, Split::Train, path, render))
        })
        .collect()
}

/// A COLMAP workspace: `images/frame_NNN.png` and `sparse/0/` in `encoding`, one OPENCV camera,
/// image ids in an order other than their names', sparse points on the surfaces with their
/// observations, and for an object-centred capture `masks/frame_NNN.png.png`.
pub fn write_colmap(
    dir: &Path,
    opts: &SynthOptions,
    layout: CaptureLayout,
    encoding: Encoding,
) -> Result<SynthScene, DataError> {
    let (scene, cameras) = capture_cameras(layout, opts);
    // COLMAP's mask name for a photo: `NAME.png`.
    let masks = layout
        .object_centred()
        .then_some((|file: &str| format!("{file}.png")) as fn(&str) -> String);
    let views = render_views(&scene, cameras, dir, |i| format!("frame_{i:03}.png"), masks)?;
    let c = &views[0].camera;
    let Distortion::Polynomial { k, p } = SYNTH_LENS else {
        unreachable!("the synthetic lens is polynomial")
    };
    let mut cameras = BTreeMap::new();
    cameras.insert(
        1,
        ColmapCamera {
            id: 1,
            model: CameraModel::Opencv,
            width: c.width,
            height: c.height,
            params: [c.fx, c.fy, c.cx, c.cy]
                .map(f64::from)
                .into_iter()
                .chain([k[0], k[1], p[0], p[1]])
                .collect(),
        },
    );
    let n = views.len();
    let mut model = ColmapModel {
        cameras,
        ..Default::default()
    };
    for (i, v) in views.iter().enumerate() {
        // Ids run backwards from the names: readers must not rely on id order.
        let id = (n - i) as u32;
        let cv = flip_yz(&v.camera.c2w);
        let rc = Mat3::from_cols(
            Vec3::new(cv[0][0], cv[1][0], cv[2][0]),
            Vec3::new(cv[0][1], cv[1][1], cv[2][1]),
            Vec3::new(cv[0][2], cv[1][2], cv[2][2]),
        );
        let r = rc.transpose().as_dmat3();
        let q = glam::DQuat::from_mat3(&r).normalize();
        let t = -(r * v.camera.origin().as_dvec3());
        let mut points2d = Vec::new();
        for (xy, p) in surface_points(v) {
            let pid = model.points.len() as u64 + 1;
            model.points.push(ColmapPoint {
                id: pid,
                xyz: p.to_array(),
                rgb: [128, 128, 128],
                error: 0.5,
                track: vec![(id, points2d.len() as u32)],
            });
            points2d.push((xy, pid as i64));
        }
        points2d.push(([1.0, 1.0], -1));
        model.images.push(ColmapImage {
            id,
            qvec: [q.w, q.x, q.y, q.z],
            tvec: t.to_array(),
            camera_id: 1,
            name: v
                .image_path
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            points2d,
        });
    }
    model.images.reverse();
    write_model(&model, &dir.join("sparse/0"), encoding)?;
    Ok(SynthScene {
        format: SceneFormat::Colmap,
        dir: dir.to_path_buf(),
        scene,
        views,
    })
}

/// Surface points a view sees, on a coarse pixel grid: `(pixel position, world point)`.
fn surface_points(v: &SynthView) -> Vec<([f64; 2], glam::DVec3)> {
    let mut out = Vec::new();
    let step = (v.camera.width / 8).max(1);
    for y in (step / 2..v.camera.height).step_by(step as usize) {
        for x in (step / 2..v.camera.width).step_by(step as usize) {
            let depth = v.render.depth[(y * v.camera.width + x) as usize];
            if depth.is_finite() {
                let (o, d) = v.camera.pixel_ray(x, y);
                out.push(([x as f64 + 0.5, y as f64 + 0.5], (o + d * depth).as_dvec3()));
            }
        }
    }
    out
}

/// A nerfstudio-style `transforms.json`: scene-wide OPENCV intrinsics with `k1 k2 p1 p2`,
/// camera-to-world matrices (OpenGL axes), `file_path`s relative to the file, every other one
/// without its extension, the surface points as `sparse_pc.ply` (`ply_file_path`), and for an
/// object-centred capture each frame's `mask_path`.
pub fn write_transforms(
    dir: &Path,
    opts: &SynthOptions,
    layout: CaptureLayout,
) -> Result<SynthScene, DataError> {
    let (scene, cameras) = capture_cameras(layout, opts);
    let with_masks = layout.object_centred();
    let masks = with_masks.then_some(str::to_string as fn(&str) -> String);
    let views = render_views(&scene, cameras, dir, |i| format!("frame_{i:05}.png"), masks)?;
    let c = &views[0].camera;
    let Distortion::Polynomial { k, p } = SYNTH_LENS else {
        unreachable!("the synthetic lens is polynomial")
    };
    let frames: Vec<_> = views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let file = if i % 2 == 0 {
                format!("images/frame_{i:05}.png")
            } else {
                format!("./images/frame_{i:05}")
            };
            let m = &v.camera.c2w;
            let mut frame = json!({ "file_path": file, "transform_matrix": [m[0], m[1], m[2], [0.0, 0.0, 0.0, 1.0]] });
            if with_masks {
                frame["mask_path"] = format!("masks/frame_{i:05}.png").into();
            }
            frame
        })
        .collect();
    let doc = json!({
        "camera_model": "OPENCV",
        "w": c.width, "h": c.height,
        "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy,
        "k1": k[0], "k2": k[1], "p1": p[0], "p2": p[1],
        "frames": frames,
        "ply_file_path": "sparse_pc.ply",
    });
    let points: Vec<glam::DVec3> = views
        .iter()
        .flat_map(|v| surface_points(v).into_iter().map(|p| p.1))
        .collect();
    write_ply_points(&dir.join("sparse_pc.ply"), &points)?;
    let path = dir.join("transforms.json");
    let text =
        serde_json::to_string_pretty(&doc).map_err(|e| DataError::json(&path, e.to_string()))?;
    std::fs::write(&path, text).map_err(|e| DataError::io(&path, e))?;
    Ok(SynthScene {
        format: SceneFormat::Transforms,
        dir: dir.to_path_buf(),
        scene,
        views,
    })
}

/// Turns every other photo of a capture [`write_transforms`] wrote (and its mask) into a
/// portrait one: the centred window three quarters as wide as the photo is high, its own `w h
/// cx cy` in its frame, as a phone mixing orientations or COLMAP's undistorter (a size per
/// photo) writes them. Returns the indices of the cropped frames.
pub fn portrait_every_other(dir: &Path) -> Result<Vec<usize>, DataError> {
    let path = dir.join("transforms.json");
    let text = std::fs::read_to_string(&path).map_err(|e| DataError::io(&path, e))?;
    let mut doc: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| DataError::json(&path, e.to_string()))?;
    let (w, h) = (
        doc["w"].as_u64().unwrap_or(0) as u32,
        doc["h"].as_u64().unwrap_or(0) as u32,
    );
    let (cx, cy) = (
        doc["cx"].as_f64().unwrap_or(0.0),
        doc["cy"].as_f64().unwrap_or(0.0),
    );
    let cw = (h * 3 / 4).min(w);
    let x0 = (w - cw) / 2;
    let crop = |file: &Path| -> Result<(), DataError> {
        let img = image::open(file).map_err(|e| DataError::invalid(file, e.to_string()))?;
        img.crop_imm(x0, 0, cw, h)
            .save(file)
            .map_err(|e| DataError::invalid(file, e.to_string()))
    };
    let frames = doc["frames"]
        .as_array_mut()
        .ok_or_else(|| DataError::json(&path, "no frames".to_string()))?;
    let mut cropped = Vec::new();
    for (i, frame) in frames.iter_mut().enumerate().filter(|(i, _)| i % 2 == 1) {
        crop(&dir.join(format!("images/frame_{i:05}.png")))?;
        if frame.get("mask_path").is_some() {
            crop(&dir.join(format!("masks/frame_{i:05}.png")))?;
        }
        frame["w"] = cw.into();
        frame["h"] = h.into();
        frame["cx"] = (cx - f64::from(x0)).into();
        frame["cy"] = cy.into();
        cropped.push(i);
    }
    let text =
        serde_json::to_string_pretty(&doc).map_err(|e| DataError::json(&path, e.to_string()))?;
    std::fs::write(&path, text).map_err(|e| DataError::io(&path, e))?;
    Ok(cropped)
}
