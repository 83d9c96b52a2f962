//! Cameras, rays, ray patches and render paths; samplers along rays (stratified, hierarchical,
//! occupancy-grid marching), volume compositing, and sphere tracing of signed distance fields.
//!
//! One camera convention for everything (see [`camera`]): camera-to-world, OpenGL axes (x right,
//! y up, looking down −z), pixel centres at `(u + 0.5, v + 0.5)`.

pub mod camera;
pub mod geometry;
pub mod mask_sampler;
pub mod occupancy;
pub mod patches;
pub mod paths;
pub mod rays;
pub mod samplers;
pub mod sphere_tracing;
pub mod volume;
