//! Rendering whole views of an IDR model in chunks, and scoring them against held-out photos:
//! silhouette IoU against the masks and PSNR inside the mask.

use std::path::Path;

use anyhow::Result;
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::psnr;
use ins_core::render::sphere_tracing::TraceOptions;
use ins_scene::camera::Camera;
use ins_scene::data::Scene;
use ins_scene::geometry::Vec3;
use ins_scene::rays::{Rays, camera_rays};

use super::model::IdrModel;
use super::render::render_surface;
use super::volume::VolumeSampling;
use super::volume_view::render_volume_view;
use crate::run::FinalScores;

/// Rays per chunk when rendering whole images.
pub const CHUNK: usize = 16384;

/// Rays per chunk of a volume render: each carries its samples' forward-mode gradients.
const VOLUME_CHUNK: usize = 4096;

/// How a whole view is rendered: the tracer that finds the surface (normals, depth, and the
/// colour of a surface-rendered model) and the samples of a volume-rendered model's colour and
/// silhouette. A run renders with its own settings ([`super::config::IdrRunConfig::view_options`]):
/// a model trained at other samples than the defaults is evaluated at those it trained with.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ViewOptions {
    /// Sphere tracing.
    pub trace: TraceOptions,
    /// Volume samples (models pretrained as a volume).
    pub sampling: VolumeSampling,
}

/// A rendered view: colour, silhouette and shaded normals.
#[derive(Debug, Clone)]
pub struct SurfaceView {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// RGB (background black), `h·w·3`.
    pub rgb: Vec<f32>,
    /// Whether each pixel's ray meets the surface.
    pub hit: Vec<bool>,
    /// Distance along each pixel's ray to the surface (meaningful where it hits).
    pub depth: Vec<f32>,
    /// Normals shaded as an image (`(n + 1) / 2`), white background.
    pub normals: Vec<f32>,
}

impl SurfaceView {
    /// The colour as an image.
    pub fn image(&self) -> RgbImage {
        RgbImage {
            width: self.width,
            height: self.height,
            data: self.rgb.clone(),
        }
    }

    /// The normals as an image.
    pub fn normal_image(&self) -> RgbImage {
        RgbImage {
            width: self.width,
            height: self.height,
            data: self.normals.clone(),
        }
    }
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("reading a render: {e:?}"))
}

/// Renders the rays of a `width × height` image in chunks (no gradient). `code`: one style
/// code `[1, n]` or `None`. A model pretrained as a volume is rendered as one (its colour,
/// and its silhouette: opacity above a half): on scan37 that scored 18.57 dB where the colour at
/// the sphere-traced surface of the same model scored 17.72. The traced surface gives the
/// normals and depth either way.
pub fn render_rays(
    model: &IdrModel,
    rays: &Rays,
    width: usize,
    height: usize,
    code: Option<Tensor<2>>,
    opts: &ViewOptions,
    device: &Device,
) -> Result<SurfaceView> {
    let n = rays.len();
    let mut view = SurfaceView {
        width,
        height,
        rgb: Vec::with_capacity(n * 3),
        hit: Vec::with_capacity(n),
        depth: Vec::with_capacity(n),
        normals: vec![1.0; n * 3],
    };
    let volume = model.sharpness.is_some();
    let chunk_rays = if volume { VOLUME_CHUNK } else { CHUNK };
    let mut start = 0;
    while start < n {
        let end = (start + chunk_rays).min(n);
        let chunk = Rays {
            origins: rays.origins[start..end].to_vec(),
            directions: rays.directions[start..end].to_vec(),
            near: rays.near[start..end].to_vec(),
            far: rays.far[start..end].to_vec(),
        };
        let out = render_surface(
            model,
            &chunk,
            code.clone(),
            [0.0; 3],
            &opts.trace,
            false,
            device,
        );
        if volume {
            let (rgb, opacity) = render_volume_view(
                model,
                &chunk,
                code.clone(),
                [0.0; 3],
                &opts.sampling,
                device,
            );
            view.rgb.extend(rgb);
            view.hit.extend(opacity.iter().map(|&o| o > 0.5));
        } else {
            view.rgb.extend(to_vec(out.rgb)?);
            view.hit.extend(out.traced.hit.iter().copied());
        }
        view.depth.extend(out.traced.t.iter().copied());
        if let Some(g) = out.surface_gradients {
            let g = to_vec(g)?;
            for (k, &i) in out.hits.iter().enumerate() {
                let v = Vec3::new(g[k * 3], g[k * 3 + 1], g[k * 3 + 2]).normalize_or_zero();
                let p = (start + i) * 3;
                view.normals[p..p + 3].copy_from_slice(&((v + Vec3::ONE) * 0.5).to_array());
            }
        }
        start = end;
    }
    Ok(view)
}

/// Renders what `camera` sees of the surface.
pub fn render_camera(
    model: &IdrModel,
    scene: &Scene,
    camera: &Camera,
    code: Option<Tensor<2>>,
    opts: &ViewOptions,
    device: &Device,
) -> Result<SurfaceView> {
    let rays = camera_rays(camera, |o, d| scene.ray_range(o, d));
    render_rays(
        model,
        &rays,
        camera.width as usize,
        camera.height as usize,
        code,
        opts,
        device,
    )
}

/// A held-out view rendered and scored.
#[derive(Debug, Clone)]
pub struct SurfaceEval {
    /// View index.
    pub view: usize,
    /// The render.
    pub render: SurfaceView,
    /// The photo.
    pub photo: Vec<f32>,
    /// The mask (1 = object).
    pub mask: Vec<bool>,
    /// Silhouette IoU of the hits against the mask.
    pub iou: f64,
    /// PSNR over the mask's pixels.
    pub psnr_mask: f64,
    /// PSNR over the whole image (background included: a run without masks learns it).
    pub psnr: f64,
}

impl SurfaceEval {
    /// photo | render | normals | silhouette (white: both, red: render only, blue: mask only).
    pub fn picture(&self) -> RgbImage {
        let r = &self.render;
        let sil: Vec<f32> = self
            .mask
            .iter()
            .zip(&r.hit)
            .flat_map(|(&m, &h)| match (m, h) {
                (true, true) => [1.0, 1.0, 1.0],
                (false, true) => [0.9, 0.1, 0.1],
                (true, false) => [0.1, 0.2, 0.9],
                (false, false) => [0.0, 0.0, 0.0],
            })
            .collect();
        let img = |data: Vec<f32>| RgbImage {
            width: r.width,
            height: r.height,
            data,
        };
        RgbImage::hstack(&[
            img(self.photo.clone()),
            r.image(),
            r.normal_image(),
            img(sil),
        ])
    }
}

/// Renders and scores `views` against the scene's masks wherever it has them, whether or not
/// the run trained with them (a run without masks is scored against masks it never saw);
/// without masks, the IoU compares with all pixels.
pub fn evaluate_views(
    model: &IdrModel,
    scene: &Scene,
    views: &[usize],
    code: Option<Tensor<2>>,
    opts: &ViewOptions,
    device: &Device,
) -> Result<Vec<SurfaceEval>> {
    let mut out = Vec::new();
    for &view in views {
        let v = scene
            .views
            .get(view)
            .ok_or_else(|| anyhow::anyhow!("view {view} does not exist"))?;
        let render = render_camera(model, scene, &v.camera, code.clone(), opts, device)?;
        let photo = v.image.to_f32();
        let mask: Vec<bool> = match &v.mask {
            Some(m) => m.data.iter().map(|&b| b >= 128).collect(),
            None => vec![true; photo.len() / 3],
        };
        let (mut inter, mut union) = (0usize, 0usize);
        let (mut se, mut count, mut se_all) = (0f64, 0usize, 0f64);
        for i in 0..mask.len() {
            let (m, h) = (mask[i], render.hit[i]);
            inter += (m && h) as usize;
            union += (m || h) as usize;
            let pixel: f64 = (0..3)
                .map(|c| {
                    ((render.rgb[i * 3 + c].clamp(0.0, 1.0) - photo[i * 3 + c]) as f64).powi(2)
                })
                .sum();
            se_all += pixel;
            if m {
                se += pixel;
                count += 3;
            }
        }
        out.push(SurfaceEval {
            view,
            iou: inter as f64 / union.max(1) as f64,
            psnr_mask: psnr(se / count.max(1) as f64),
            psnr: psnr(se_all / photo.len().max(1) as f64),
            render,
            photo,
            mask,
        });
    }
    Ok(out)
}

/// The means of `evals`' scores (`iou`, `psnr_mask`, `psnr`; PSNR averaged in dB, view by
/// view, as `eval idr` does) and their count (`views`).
pub fn mean_scores(evals: &[SurfaceEval]) -> FinalScores {
    let n = evals.len().max(1) as f64;
    let mean = |f: fn(&SurfaceEval) -> f64| evals.iter().map(f).sum::<f64>() / n;
    FinalScores::from([
        ("views".into(), evals.len() as f64),
        ("iou".into(), mean(|e| e.iou)),
        ("psnr_mask".into(), mean(|e| e.psnr_mask)),
        ("psnr".into(), mean(|e| e.psnr)),
    ])
}

/// Stacks evaluation pictures into one PNG.
pub fn save_pictures(evals: &[SurfaceEval], path: &Path) -> Result<()> {
    let pictures: Vec<RgbImage> = evals.iter().map(|e| e.picture()).collect();
    RgbImage::vstack(&pictures).save(path)
}
