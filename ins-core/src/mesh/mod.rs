//! Meshes out of implicit surfaces: marching cubes of a sampled field, written as binary PLY
//! or binary glTF, and scored against a reference surface.

mod cube_tables;
#[cfg(test)]
mod file_tests;
pub mod glb;
pub mod marching_cubes;
pub mod nearest_points;
pub mod surface_distance;
pub mod triangle_mesh;
pub mod visibility;

pub use marching_cubes::{Grid, marching_cubes};
pub use surface_distance::{SurfaceDistance, sample_surface, surface_distance};
pub use triangle_mesh::Mesh;
