//! Meshes out of implicit surfaces: marching cubes of a sampled field, written as binary PLY
//! or binary glTF.

mod cube_tables;
#[cfg(test)]
mod file_tests;
pub mod glb;
pub mod marching_cubes;
pub mod triangle_mesh;

pub use marching_cubes::{Grid, marching_cubes};
pub use triangle_mesh::Mesh;
