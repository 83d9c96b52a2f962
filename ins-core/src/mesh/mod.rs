//! Meshes out of implicit surfaces: marching cubes of a sampled signed distance field, and
//! binary PLY files any mesh viewer opens.

pub mod marching_cubes;

pub use marching_cubes::{Grid, Mesh, marching_cubes};
