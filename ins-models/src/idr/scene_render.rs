//! An IDR run as a 3D scene: frames sphere-traced to the SDF's zero set, and that surface as a
//! mesh.

use anyhow::{Result, bail};
use burn::prelude::*;
use ins_scene::camera::Camera;
use ins_scene::data::Scene;
use ins_scene::paths::scene_up;

use super::eval::render_camera;
use super::mesh::extract_mesh;
use super::run::IdrRun;
use crate::run::scene_render::{MeshOptions, PathFrame, RunMesh, SceneRender};

impl SceneRender for IdrRun {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn scene(&self) -> &Scene {
        &self.data
    }

    fn frame(&self, cam: &Camera, code: Option<Tensor<2>>, device: &Device) -> Result<PathFrame> {
        let r = render_camera(
            &self.model.valid(),
            self.scene(),
            cam,
            code,
            &self.config.view_options(),
            device,
        )?;
        let rays = ins_scene::rays::camera_rays(cam, |o, d| self.scene().ray_range(o, d));
        let depth: Vec<Option<f32>> = (0..r.hit.len())
            .map(|i| r.hit[i].then(|| r.depth[i]))
            .collect();
        let points = depth
            .iter()
            .enumerate()
            .map(|(i, t)| t.map(|t| rays.point(i, t)))
            .collect();
        Ok(PathFrame {
            image: r.image(),
            points,
            depth_picture: ins_core::imaging::surface_depth_image(&depth, r.width, r.height),
            depth,
        })
    }

    fn mesh(&self, how: MeshOptions, code: Option<Tensor<2>>, device: &Device) -> Result<RunMesh> {
        if how.level.is_some() {
            bail!("--level is a NeRF density; an IDR run is meshed at its SDF's zero set");
        }
        let started = std::time::Instant::now();
        let (mesh, colors) = extract_mesh(&self.model.valid(), how.resolution, code, device)?;
        Ok(RunMesh {
            mesh,
            colors,
            up: scene_up(self.scene()),
            info: serde_json::json!({"seconds": started.elapsed().as_secs_f64()}),
        })
    }
}
