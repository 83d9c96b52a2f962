//! The one interface of a 3D run (NeRF, IDR), whichever variant: frames from any camera (what
//! the viewer, `render`, `eval consistency` and the report draw) and the surface as a mesh
//! (what `export mesh` writes). [`super::any::AnyRun`] hands a run out as a
//! `Box<dyn SceneRender>`.

use std::any::Any;
use std::path::Path;

use anyhow::Result;
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::mesh::Mesh;
use ins_scene::camera::Camera;
use ins_scene::data::Scene;
use ins_scene::geometry::Vec3;

use super::args::StyleArgs;
use super::lifecycle::Run;
use super::variant::{RunConfig, Variant};

/// One rendered frame, as the viewer and the evaluation read it.
#[derive(Debug, Clone)]
pub struct PathFrame {
    /// The picture.
    pub image: RgbImage,
    /// The surface point each pixel sees, where it sees the object (NeRF: opacity above 0.5;
    /// IDR: the ray meets the surface).
    pub points: Vec<Option<Vec3>>,
    /// The distance along each pixel's ray to that point.
    pub depth: Vec<Option<f32>>,
    /// The depth as a colour-mapped picture.
    pub depth_picture: RgbImage,
}

impl PathFrame {
    /// Pixels on the object.
    pub fn object(&self) -> Vec<bool> {
        self.points.iter().map(Option::is_some).collect()
    }
}

/// How to mesh a run's surface.
#[derive(Debug, Clone, Copy)]
pub struct MeshOptions {
    /// Samples along the longest side of the grid marching cubes runs on.
    pub resolution: usize,
    /// NeRF: the density of the surface (default: the run's own, read off its renders); IDR
    /// meshes its SDF's zero set and refuses a level.
    pub level: Option<f32>,
}

/// A run's surface as a mesh, with a colour per vertex.
pub struct RunMesh {
    /// Vertices, normals and triangles.
    pub mesh: Mesh,
    /// The (stylized) colour of each vertex.
    pub colors: Vec<[u8; 3]>,
    /// The scene's up direction (glTF's +Y).
    pub up: Vec3,
    /// What the variant adds to the exporter's summary (NeRF: the level and box), and the
    /// seconds marching cubes took.
    pub info: serde_json::Value,
}

/// What any run answers, whichever variant: its folder, paintings, pretrained run and style
/// codes.
pub trait RunInfo {
    /// The run folder.
    fn dir(&self) -> &Path;
    /// The run's paintings and perceptual settings (empty for a pretrained run).
    fn style(&self) -> &StyleArgs;
    /// The pretrained run a stylized run started from.
    fn base_run(&self) -> Option<&Path>;
    /// A style code `[1, n]` from mix weights (normalised; default: the first style), or
    /// `None` for an unstylized run (where a mix is an error naming the run).
    fn code(&self, mix: Option<&[f32]>, device: &Device) -> Result<Option<Tensor<2>>>;
}

impl<V: Variant> RunInfo for Run<V> {
    fn dir(&self) -> &Path {
        &self.dir
    }

    fn style(&self) -> &StyleArgs {
        self.config.style()
    }

    fn base_run(&self) -> Option<&Path> {
        self.config.base_run()
    }

    fn code(&self, mix: Option<&[f32]>, device: &Device) -> Result<Option<Tensor<2>>> {
        Run::code(self, mix, device)
    }
}

/// A 3D run: frames from any camera, and its surface.
pub trait SceneRender: RunInfo {
    /// The run's scene (cameras, photos, bounds).
    fn scene(&self) -> &Scene;
    /// Renders what `camera` sees under style `code` (`None`: unstylized).
    fn frame(&self, camera: &Camera, code: Option<Tensor<2>>, device: &Device)
    -> Result<PathFrame>;
    /// The surface as a mesh coloured under `code`.
    fn mesh(
        &self,
        options: MeshOptions,
        code: Option<Tensor<2>>,
        device: &Device,
    ) -> Result<RunMesh>;
    /// The run as `Any`, so that a variant can tell a run of its own kind
    /// ([`Self::frame_pair`]).
    fn as_any(&self) -> &dyn Any;
    /// What `camera` sees from `base` unstylized (the pretrained run this run started from)
    /// and from this run under `code`. Two renders, unless the variant can share the work: a
    /// NeRF stylized with its base's density kept renders the geometry once for both.
    fn frame_pair(
        &self,
        base: &dyn SceneRender,
        camera: &Camera,
        code: Option<Tensor<2>>,
        device: &Device,
    ) -> Result<(PathFrame, PathFrame)> {
        Ok((
            base.frame(camera, None, device)?,
            self.frame(camera, code, device)?,
        ))
    }
}
