//! Meshes out of implicit surfaces: marching cubes of a sampled signed distance field, and
//! binary PLY files any mesh viewer opens.

mod cube_tables;
pub mod marching_cubes;
pub mod triangle_mesh;

pub use marching_cubes::{Grid, marching_cubes};
pub use triangle_mesh::Mesh;
