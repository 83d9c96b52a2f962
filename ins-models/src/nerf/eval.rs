//! Rendering whole views in chunks (bounded memory at any resolution) and scoring them against
//! the held-out photos: PSNR, SSIM, and a picture (photo | render | depth) per view.

use std::path::Path;

use anyhow::Result;
use burn::prelude::*;
use ins_core::eval::depth::DepthAgreement;
use ins_core::imaging::{RgbImage, surface_depth_image};
use ins_core::loss::{psnr, ssim};
use ins_scene::camera::Camera;
use ins_scene::data::Scene;
use ins_scene::geometry::Vec3;
use ins_scene::rays::camera_rays;

use super::early_stop::{INVISIBLE_TRANSMITTANCE, Look, render_looks};
use super::model::NerfModel;
use super::render::{RenderRays, Sampling, render};

/// Rays per chunk when rendering whole images.
pub const CHUNK: usize = 8192;

/// A rendered image with its depth and opacity.
#[derive(Debug, Clone)]
pub struct ViewRender {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// RGB, `h·w·3`.
    pub rgb: Vec<f32>,
    /// Expected ray distance (not divided by opacity), `h·w`.
    pub depth: Vec<f32>,
    /// Opacity, `h·w`.
    pub opacity: Vec<f32>,
}

impl ViewRender {
    /// The colour as an image.
    pub fn image(&self) -> RgbImage {
        RgbImage {
            width: self.width,
            height: self.height,
            data: self.rgb.clone(),
        }
    }

    /// The depth as a colour-mapped image over the opaque pixels' range.
    pub fn depth_picture(&self) -> RgbImage {
        surface_depth_image(&self.surface_depth(), self.width, self.height)
    }

    /// The distance along each pixel's ray to the surface it sees (the expected ray distance
    /// over the opacity), `None` where the opacity is 0.5 or below.
    pub fn surface_depth(&self) -> Vec<Option<f32>> {
        self.depth
            .iter()
            .zip(&self.opacity)
            .map(|(d, o)| (*o > 0.5).then(|| d / o))
            .collect()
    }

    /// The surface point each pixel sees (the expected ray distance over the opacity), in the
    /// scene frame, for a render of `camera` in `scene`; `None` where the opacity is below 0.5.
    /// Forward-facing scenes render in NDC; their points are mapped back to the world ray.
    pub fn surface_points(&self, scene: &Scene, camera: &Camera) -> Vec<Option<Vec3>> {
        let world = camera_rays(camera, |o, d| scene.ray_range(o, d));
        let ndc = scene
            .forward_facing
            .then(|| RenderRays::for_scene(scene, world.clone()).rays);
        (0..self.opacity.len())
            .map(|i| {
                let o = self.opacity[i];
                if o <= 0.5 {
                    return None;
                }
                let t = self.depth[i] / o;
                match &ndc {
                    None => Some(world.point(i, t)),
                    Some(ndc) => {
                        // NDC z = 1 + 2·near/z_world with near = 1 (see `Rays::to_ndc`).
                        let z_ndc = ndc.point(i, t).z;
                        if z_ndc >= 1.0 {
                            return None;
                        }
                        let z = 2.0 / (z_ndc - 1.0);
                        let (wo, wd) = (world.origins[i], world.directions[i]);
                        Some(wo + wd * ((z - wo.z) / wd.z))
                    }
                }
            })
            .collect()
    }
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("reading a render: {e:?}"))
}

/// Relative depth error and opacity agreement of two renders of one view (see
/// [`DepthAgreement`]).
pub fn depth_agreement(student: &ViewRender, teacher: &ViewRender) -> DepthAgreement {
    DepthAgreement::of(&student.surface_depth(), &teacher.surface_depth())
}

/// Renders `rays` (an image's rays, row major) in chunks of [`CHUNK`] with a fixed sampling
/// (no jitter); marched rays stop once opaque
/// ([`render_early_stop`](super::early_stop::render_early_stop)). `code` is one style code `[1, n_styles]` or `None` for the unstylized field.
#[allow(clippy::too_many_arguments)]
pub fn render_rays(
    model: &NerfModel,
    rays: &RenderRays,
    width: usize,
    height: usize,
    sampling: Sampling,
    code: Option<Tensor<2>>,
    background: [f32; 3],
    device: &Device,
) -> Result<ViewRender> {
    let look = Look {
        model,
        code,
        background,
    };
    let mut views = render_rays_looks(&[look], rays, width, height, sampling, device)?;
    Ok(views.remove(0))
}

/// [`render_rays`] of several looks: marched, they share one pass of the first look's
/// geometry ([`render_looks`]); sampled coarse to fine, each is rendered on its own.
pub fn render_rays_looks(
    looks: &[Look],
    rays: &RenderRays,
    width: usize,
    height: usize,
    sampling: Sampling,
    device: &Device,
) -> Result<Vec<ViewRender>> {
    let n = rays.len();
    let mut out: Vec<ViewRender> = looks
        .iter()
        .map(|_| ViewRender {
            width,
            height,
            rgb: Vec::with_capacity(n * 3),
            depth: Vec::with_capacity(n),
            opacity: Vec::with_capacity(n),
        })
        .collect();
    let mut start = 0;
    while start < n {
        let end = (start + CHUNK).min(n);
        let chunk = rays.slice(start, end);
        if let Sampling::Occupancy {
            grid, max_per_ray, ..
        } = sampling
        {
            let (rgb, depth, opacity) = render_looks(
                looks,
                &chunk,
                grid,
                max_per_ray,
                INVISIBLE_TRANSMITTANCE,
                device,
            )?;
            for (view, rgb) in out.iter_mut().zip(rgb) {
                view.rgb.extend(rgb);
                view.depth.extend_from_slice(&depth);
                view.opacity.extend_from_slice(&opacity);
            }
        } else {
            for (view, look) in out.iter_mut().zip(looks) {
                let r = render(
                    look.model,
                    &chunk,
                    sampling,
                    look.code.clone(),
                    look.background,
                    None,
                    device,
                );
                view.rgb.extend(to_vec(r.fine.rgb)?);
                view.depth.extend(to_vec(r.fine.depth)?);
                view.opacity.extend(to_vec(r.fine.opacity)?);
            }
        }
        start = end;
    }
    Ok(out)
}

/// Renders the view of `camera` in `scene`'s frame.
pub fn render_camera(
    model: &NerfModel,
    scene: &Scene,
    camera: &Camera,
    sampling: Sampling,
    code: Option<Tensor<2>>,
    background: [f32; 3],
    device: &Device,
) -> Result<ViewRender> {
    let look = Look {
        model,
        code,
        background,
    };
    let mut views = render_camera_looks(&[look], scene, camera, sampling, device)?;
    Ok(views.remove(0))
}

/// [`render_camera`] of several looks ([`render_rays_looks`]).
pub fn render_camera_looks(
    looks: &[Look],
    scene: &Scene,
    camera: &Camera,
    sampling: Sampling,
    device: &Device,
) -> Result<Vec<ViewRender>> {
    let rays = RenderRays::for_scene(scene, camera_rays(camera, |o, d| scene.ray_range(o, d)));
    render_rays_looks(
        looks,
        &rays,
        camera.width as usize,
        camera.height as usize,
        sampling,
        device,
    )
}

/// One held-out view, rendered and scored.
#[derive(Debug, Clone)]
pub struct ViewEval {
    /// View index in the scene.
    pub view: usize,
    /// The render.
    pub render: ViewRender,
    /// The photo, `h·w·3`.
    pub photo: Vec<f32>,
    /// PSNR in dB.
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
}

impl ViewEval {
    /// photo | render | depth.
    pub fn picture(&self, _scene: &Scene) -> RgbImage {
        let r = &self.render;
        RgbImage::hstack(&[
            RgbImage {
                width: r.width,
                height: r.height,
                data: self.photo.clone(),
            },
            r.image(),
            r.depth_picture(),
        ])
    }
}

/// Renders and scores `views` of `scene`.
pub fn evaluate_views(
    model: &NerfModel,
    scene: &Scene,
    views: &[usize],
    sampling: Sampling,
    code: Option<Tensor<2>>,
    background: [f32; 3],
    device: &Device,
) -> Result<Vec<ViewEval>> {
    let mut out = Vec::with_capacity(views.len());
    for &view in views {
        let v = scene
            .views
            .get(view)
            .ok_or_else(|| anyhow::anyhow!("view {view} does not exist"))?;
        let render = render_camera(
            model,
            scene,
            &v.camera,
            sampling,
            code.clone(),
            background,
            device,
        )?;
        let photo = v.image.to_f32();
        let mse = render
            .rgb
            .iter()
            .zip(&photo)
            .map(|(a, b)| ((a.clamp(0.0, 1.0) - b) as f64).powi(2))
            .sum::<f64>()
            / photo.len() as f64;
        let s = ssim(&render.rgb, &photo, render.width, render.height);
        out.push(ViewEval {
            view,
            render,
            photo,
            psnr: psnr(mse),
            ssim: s,
        });
    }
    Ok(out)
}

/// Stacks evaluation pictures into one PNG.
pub fn save_eval_picture(pictures: &[RgbImage], path: &Path) -> Result<()> {
    RgbImage::vstack(pictures).save(path)
}
