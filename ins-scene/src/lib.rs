//! Scenes and cameras, the ground floor of INS-rs: posed images read from the real dataset
//! formats ([`data`]), one camera convention ([`camera`], [`geometry`]), and the rays, ray
//! patches and camera paths drawn from them ([`rays`], [`patches`], [`mask_sampler`],
//! [`paths`]).
//!
//! No tensors here: the crate builds without Burn, so the format readers and their tests
//! compile in seconds and every layer above (rendering, models, training) reads scenes
//! through one type.
//!
//! One camera convention for everything: camera-to-world, OpenGL axes (x right, y up, looking
//! down −z), pixel centres at `(u + 0.5, v + 0.5)`.

pub mod camera;
pub mod data;
pub mod distortion;
pub mod geometry;
pub mod mask_sampler;
pub mod patches;
pub mod paths;
pub mod rays;
pub mod stats;
pub mod viewpoints;
