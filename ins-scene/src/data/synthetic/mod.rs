//! Small analytic scenes (spheres, boxes, planes, procedural checker textures), ray-cast with
//! exact depth and masks, and written out in the Blender, LLFF, DTU/IDR, COLMAP and transforms.json formats.
//!
//! They prove the geometry: a test writes a scene, reads it back through the real loader, and
//! checks that the loaded ray of a pixel meets the surface point that was rendered there, at the
//! depth that was rendered. One sample per pixel, at its centre, so the colour and depth of a
//! pixel belong to exactly that pixel's ray.

mod analytic;
mod capture_writers;
mod reference_surface;
mod writers;

pub use analytic::*;
pub use capture_writers::*;
pub use writers::*;
