//! What the viewer renders: a NeRF or IDR run seen from a [`ViewerPose`], or a SIREN run's
//! image panned and zoomed, under a style mix, in bands of rows so a newer request can cancel
//! a render in flight between bands.

use std::path::Path;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::imaging::{RgbImage, surface_depth_image};
use ins_models::image_task::render_window;
use ins_models::run::{AnyRun, SceneRender};
use ins_models::siren::SirenRun;
use ins_scene::camera::Camera;
use ins_scene::geometry::Vec3;
use ins_scene::viewpoints::{ViewerPose, Viewpoints};
use serde_json::{Value, json};

/// What a picture shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// The (stylized) colour.
    Color,
    /// Distance along the ray, colour-mapped over the picture's range.
    Depth,
    /// Surface normals from neighbouring surface points, in camera axes.
    Normals,
    /// White where the ray meets the object.
    Silhouette,
}

impl Mode {
    /// Parses `color|depth|normals|silhouette`.
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "color" | "" => Self::Color,
            "depth" => Self::Depth,
            "normals" => Self::Normals,
            "silhouette" => Self::Silhouette,
            other => bail!("mode {other:?}: expected color, depth, normals or silhouette"),
        })
    }
}

/// One picture to render.
#[derive(Clone, Debug)]
pub struct ViewRequest {
    /// Size in pixels.
    pub width: u32,
    /// Size in pixels.
    pub height: u32,
    /// Camera (3D) or pan/zoom (SIREN: `pan` is the centre, `distance` the inverse zoom).
    pub pose: ViewerPose,
    /// Style weights (empty: the run's default).
    pub mix: Vec<f32>,
    /// What to show.
    pub mode: Mode,
}

/// Rows per band: a band's rays take a fraction of a second on two cores.
const BAND_PIXELS: usize = 24_000;

/// A run the viewer shows.
pub enum Source {
    /// NeRF or IDR.
    Scene {
        run: Box<dyn SceneRender>,
        viewpoints: Viewpoints,
        variant: &'static str,
    },
    /// SIREN.
    Image(SirenRun),
}

impl Source {
    /// Loads the run folder `dir`, whichever variant wrote it.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        let run = AnyRun::load(dir, device)?;
        let variant = run.variant().key();
        let run = match run {
            AnyRun::Siren(run) => return Ok(Self::Image(run)),
            scene => scene.into_scene("a 3D view")?,
        };
        let viewpoints = Viewpoints::for_scene(run.scene())
            .with_context(|| format!("{}: the scene has no training views", dir.display()))?;
        Ok(Self::Scene {
            run,
            viewpoints,
            variant,
        })
    }

    /// The pose a pose request is held to.
    pub fn clamp(&self, pose: ViewerPose) -> ViewerPose {
        match self {
            Self::Scene { viewpoints, .. } => viewpoints.clamp(pose),
            Self::Image(_) => ViewerPose {
                azimuth: 0.0,
                elevation: 0.0,
                distance: if pose.distance.is_finite() {
                    pose.distance.clamp(0.01, 4.0)
                } else {
                    1.0
                },
                pan: pose.pan.map(|v| {
                    if v.is_finite() {
                        v.clamp(-2.0, 2.0)
                    } else {
                        0.0
                    }
                }),
            },
        }
    }

    /// What the page needs: the variant, style names, the home pose, the training aspect.
    pub fn info(&self) -> Value {
        match self {
            Self::Scene {
                run,
                viewpoints,
                variant,
            } => {
                let scene = run.scene();
                let t = &scene.views[scene.split(ins_scene::data::Split::Train)[0]].camera;
                json!({
                    "variant": variant,
                    "styles": style_names(&run.style().styles),
                    "home": viewpoints.home(),
                    "forward_facing": viewpoints.forward_facing(),
                    "azimuth_range": viewpoints.azimuth_range(),
                    "elevation_range": viewpoints.elevation_range(),
                    "aspect": t.width as f32 / t.height.max(1) as f32,
                    "modes": ["color", "depth", "normals", "silhouette"],
                })
            }
            Self::Image(run) => {
                let (w, h) = run.training_size();
                json!({
                    "variant": "siren",
                    "styles": style_names(&run.config.style.styles),
                    "home": ViewerPose { azimuth: 0.0, elevation: 0.0, distance: 1.0, pan: [0.0, 0.0] },
                    "forward_facing": false,
                    "aspect": w as f32 / h.max(1) as f32,
                    "modes": ["color"],
                })
            }
        }
    }

    /// The camera of a request (3D runs).
    pub fn camera(&self, req: &ViewRequest) -> Option<Camera> {
        match self {
            Self::Scene { viewpoints, .. } => {
                Some(viewpoints.camera(req.pose, req.width, req.height))
            }
            Self::Image(_) => None,
        }
    }

    /// Renders `req`, band by band; `Ok(None)` when `cancelled()` turns true between bands.
    pub fn render(
        &self,
        req: &ViewRequest,
        device: &Device,
        cancelled: &dyn Fn() -> bool,
    ) -> Result<Option<RgbImage>> {
        let (w, h) = (req.width as usize, req.height as usize);
        let band = (BAND_PIXELS / w.max(1)).max(1);
        match self {
            Self::Image(run) => {
                if req.mode != Mode::Color {
                    bail!("a SIREN run shows colour only");
                }
                let n = run.model.n_styles();
                let mix = if req.mix.is_empty() {
                    None
                } else {
                    Some(req.mix.as_slice())
                };
                let code = ins_models::style_mix::normalized(n, mix)?;
                let zoom = 1.0 / req.pose.distance;
                let mut data = Vec::with_capacity(w * h * 3);
                for y0 in (0..h).step_by(band) {
                    if cancelled() {
                        return Ok(None);
                    }
                    let rows = band.min(h - y0);
                    let img = render_window(
                        &run.model,
                        w,
                        h,
                        y0..y0 + rows,
                        req.pose.pan,
                        zoom,
                        &code,
                        device,
                    )?;
                    data.extend(img.data);
                }
                Ok(Some(RgbImage {
                    width: w,
                    height: h,
                    data,
                }))
            }
            Self::Scene { run, .. } => {
                let cam = self.camera(req).expect("a scene has cameras");
                let code = run.code(
                    if req.mix.is_empty() {
                        None
                    } else {
                        Some(&req.mix)
                    },
                    device,
                )?;
                let mut rgb = Vec::with_capacity(w * h * 3);
                let mut depth = Vec::with_capacity(w * h);
                let mut points = Vec::with_capacity(w * h);
                for y0 in (0..h).step_by(band) {
                    if cancelled() {
                        return Ok(None);
                    }
                    let rows = band.min(h - y0);
                    let crop = Camera {
                        height: rows as u32,
                        cy: cam.cy - y0 as f32,
                        ..cam.clone()
                    };
                    let f = run.frame(&crop, code.clone(), device)?;
                    rgb.extend(f.image.data);
                    depth.extend(f.depth);
                    points.extend(f.points);
                }
                Ok(Some(picture(req.mode, w, h, rgb, &depth, &points, &cam)))
            }
        }
    }
}

/// The file stems of the style images.
fn style_names(styles: &[std::path::PathBuf]) -> Vec<String> {
    styles
        .iter()
        .map(|p| {
            p.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| p.display().to_string())
        })
        .collect()
}

/// The picture of `mode` from a whole frame's colour, depth and surface points.
fn picture(
    mode: Mode,
    w: usize,
    h: usize,
    rgb: Vec<f32>,
    depth: &[Option<f32>],
    points: &[Option<Vec3>],
    cam: &Camera,
) -> RgbImage {
    let data = match mode {
        Mode::Color => rgb,
        Mode::Silhouette => depth
            .iter()
            .flat_map(|d| [if d.is_some() { 1.0 } else { 0.0 }; 3])
            .collect(),
        Mode::Depth => return surface_depth_image(depth, w, h),
        Mode::Normals => {
            let rot = cam.rotation().transpose();
            let at = |x: usize, y: usize| points[y * w + x];
            let mut out = vec![0f32; w * h * 3];
            for y in 0..h {
                for x in 0..w {
                    let (Some(_), Some(l), Some(r), Some(u), Some(d)) = (
                        at(x, y),
                        at(x.saturating_sub(1), y),
                        at((x + 1).min(w - 1), y),
                        at(x, y.saturating_sub(1)),
                        at(x, (y + 1).min(h - 1)),
                    ) else {
                        continue;
                    };
                    // Camera axes: x right, y up, z back (towards the viewer).
                    let mut n = rot * (r - l).cross(u - d).normalize_or_zero();
                    if n.z < 0.0 {
                        n = -n;
                    }
                    let i = (y * w + x) * 3;
                    out[i..i + 3].copy_from_slice(&(n * 0.5 + Vec3::splat(0.5)).to_array());
                }
            }
            out
        }
    };
    RgbImage {
        width: w,
        height: h,
        data,
    }
}
