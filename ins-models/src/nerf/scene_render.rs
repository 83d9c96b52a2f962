//! A NeRF run as a 3D scene: frames rendered through the occupancy grid (or coarse-fine
//! samples), the surface where the opacity passes one half, and the density's level set as a
//! mesh.

use std::any::Any;

use anyhow::Result;
use burn::module::{ModuleVisitor, Param};
use burn::prelude::*;
use ins_scene::camera::Camera;
use ins_scene::data::Scene;
use ins_scene::paths::scene_up;

use super::early_stop::Look;
use super::eval::{ViewRender, render_camera, render_camera_looks};
use super::mesh::{extract_mesh, half_opaque_density};
use super::render::Sampling;
use super::run::NerfRun;
use crate::run::scene_render::{MeshOptions, PathFrame, RunMesh, SceneRender};

/// A frame as the viewer and the evaluation read it.
fn path_frame(r: &ViewRender, scene: &Scene, cam: &Camera) -> PathFrame {
    PathFrame {
        image: r.image(),
        points: r.surface_points(scene, cam),
        depth: r.surface_depth(),
        depth_picture: r.depth_picture(),
    }
}

/// Whether `a` renders exactly `b`'s geometry: both march the same occupancy grid as far, keep
/// their content module's density, hold the same content module and frame rays alike (a
/// stylization that kept its pretrained run's density).
fn shares_geometry(a: &NerfRun, b: &NerfRun) -> bool {
    let marching = match (a.sampling(), b.sampling()) {
        (
            Sampling::Occupancy {
                grid: ga,
                max_per_ray: ma,
                ..
            },
            Sampling::Occupancy {
                grid: gb,
                max_per_ray: mb,
                ..
            },
        ) => ga == gb && ma == mb,
        _ => false,
    };
    let (sa, sb) = (a.scene(), b.scene());
    let framing = (sa.near, sa.far, sa.per_ray_range, sa.forward_facing)
        == (sb.near, sb.far, sb.per_ray_range, sb.forward_facing)
        && sa.bounds == sb.bounds
        && sa.contraction == sb.contraction;
    marching
        && framing
        && a.model.density_is_geometry()
        && b.model.density_is_geometry()
        && same_values(&a.model.field.geometry, &b.model.field.geometry)
}

/// Whether two modules of one kind hold the same parameter values (a value that cannot be
/// read counts as different).
fn same_values<M: Module>(a: &M, b: &M) -> bool {
    #[derive(Default)]
    struct Values(Vec<Option<Vec<f32>>>);
    impl ModuleVisitor for Values {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let data = param.val().into_data().convert::<f32>();
            self.0.push(data.try_to_vec::<f32>().ok());
        }
    }
    let (mut va, mut vb) = (Values::default(), Values::default());
    a.visit(&mut va);
    b.visit(&mut vb);
    va.0.iter().all(Option::is_some) && va.0 == vb.0
}

impl SceneRender for NerfRun {
    fn scene(&self) -> &Scene {
        &self.data.scene
    }

    fn frame(&self, cam: &Camera, code: Option<Tensor<2>>, device: &Device) -> Result<PathFrame> {
        let r = render_camera(
            &self.model.valid(),
            self.scene(),
            cam,
            self.sampling(),
            code,
            self.background(),
            device,
        )?;
        Ok(path_frame(&r, self.scene(), cam))
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    fn frame_pair(
        &self,
        base: &dyn SceneRender,
        cam: &Camera,
        code: Option<Tensor<2>>,
        device: &Device,
    ) -> Result<(PathFrame, PathFrame)> {
        let shared = base
            .as_any()
            .downcast_ref::<NerfRun>()
            .filter(|base| shares_geometry(self, base));
        let Some(base) = shared else {
            return Ok((
                base.frame(cam, None, device)?,
                self.frame(cam, code, device)?,
            ));
        };
        let (pretrained, stylized) = (base.model.valid(), self.model.valid());
        let looks = [
            Look {
                model: &pretrained,
                code: None,
                background: base.background(),
            },
            Look {
                model: &stylized,
                code,
                background: self.background(),
            },
        ];
        let views = render_camera_looks(&looks, self.scene(), cam, self.sampling(), device)?;
        Ok((
            path_frame(&views[0], self.scene(), cam),
            path_frame(&views[1], self.scene(), cam),
        ))
    }

    fn mesh(&self, how: MeshOptions, code: Option<Tensor<2>>, device: &Device) -> Result<RunMesh> {
        let started = std::time::Instant::now();
        let m = extract_mesh(
            self,
            &self.model.valid(),
            how.resolution,
            how.level,
            code,
            device,
        )?;
        let info = serde_json::json!({
            "level": m.level,
            "level_floor": half_opaque_density(self),
            "grid": m.resolution,
            "box": [m.bounds.0.to_array(), m.bounds.1.to_array()],
            "seconds": started.elapsed().as_secs_f64(),
        });
        Ok(RunMesh {
            mesh: m.mesh,
            colors: m.colors,
            up: scene_up(self.scene()),
            info,
        })
    }
}
