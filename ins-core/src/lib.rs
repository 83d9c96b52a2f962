//! INS-rs core: the parts every stylized implicit representation shares.
//!
//! Data flows one way: [`data`] (posed images) → [`render`] (cameras, rays, samplers,
//! renderers) → [`modules`] (SIM / CIM / AM) → [`loss`] → [`train`] (the one trainer).
//! [`backend`] picks the compute device at run time; [`imaging`] turns tensors into pictures.

// Burn's `slice` takes one range per dimension, so `[a..b]` on a 1-D tensor is the idiom.
#![allow(clippy::single_range_in_vec_init)]

pub mod backend;
pub mod contain;
pub mod eval;
mod flex_kernels;
pub mod gpu;
pub mod gpu_failure;
pub mod imaging;
pub mod loss;
pub mod mesh;
pub mod modules;
pub mod render;
pub mod shape_buckets;
pub mod train;
