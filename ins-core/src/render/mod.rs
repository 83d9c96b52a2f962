//! Cameras, rays, ray patches and render paths.
//!
//! One camera convention for everything (see [`camera`]): camera-to-world, OpenGL axes (x right,
//! y up, looking down −z), pixel centres at `(u + 0.5, v + 0.5)`.

pub mod camera;
pub mod geometry;
pub mod patches;
pub mod paths;
pub mod rays;
