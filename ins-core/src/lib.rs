//! INS-rs core: the parts every stylized implicit representation shares.
//!
//! Data flows one way: [`data`] (posed images) → [`render`] (cameras, rays, samplers,
//! renderers) → [`modules`] (SIM / CIM / AM) → [`loss`] → [`train`] (the one trainer).
//! [`backend`] picks the compute device at run time; [`imaging`] turns tensors into pictures.

pub mod backend;
pub mod contain;
pub mod data;
pub mod eval;
mod flex_kernels;
pub mod imaging;
pub mod loss;
pub mod mesh;
pub mod modules;
pub mod render;
pub mod train;
