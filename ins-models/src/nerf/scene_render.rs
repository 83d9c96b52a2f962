//! A NeRF run as a 3D scene: frames rendered through the occupancy grid (or coarse-fine
//! samples), the surface where the opacity passes one half, and the density's level set as a
//! mesh.

use anyhow::Result;
use burn::prelude::*;
use ins_scene::camera::Camera;
use ins_scene::data::Scene;
use ins_scene::paths::scene_up;

use super::eval::render_camera;
use super::mesh::{extract_mesh, half_opaque_density};
use super::run::NerfRun;
use crate::run::scene_render::{MeshOptions, PathFrame, RunMesh, SceneRender};

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
        let points = r.surface_points(self.scene(), cam);
        Ok(PathFrame {
            image: r.image(),
            points,
            depth: r.surface_depth(),
            depth_picture: r.depth_picture(),
        })
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
