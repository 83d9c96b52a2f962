//! INS-rs core: the parts every stylized implicit representation shares, on Burn tensors.
//! Scenes, cameras and rays come from `ins-scene` (no tensors there); the variants and the run
//! lifecycle live in `ins-models`.
//!
//! A step flows one way: rays (from `ins-scene`) → [`render`] (samplers, occupancy-grid
//! marching, volume compositing, sphere tracing) → [`modules`] (SIM / CIM / AM, hash grids,
//! SDFs) → [`loss`] (VGG style and content, pixel, colour transfer) → [`train`] (the one
//! trainer: phases, optimizer groups, checkpoints, metrics).
//!
//! Beside them: [`kernels`] (every op with a hand-written backward, and the fused Adam step),
//! [`eval`] (view consistency, texture on the object, depth kept), [`mesh`] (marching cubes,
//! PLY, glTF), [`imaging`] (tensors to pictures), [`backend`] and [`gpu`] (the compute device
//! chosen at run time, wgpu's set-up and its failures), [`shape_buckets`] (GPU sizes rounded so
//! kernels compile once), [`contain`] (a decoder's panic on damaged input turned into an error).

// Burn's `slice` takes one range per dimension, so `[a..b]` on a 1-D tensor is the idiom.
#![allow(clippy::single_range_in_vec_init)]

pub mod backend;
pub mod contain;
pub mod cuda;
pub mod eval;
pub mod gpu;
pub mod gpu_failure;
pub mod imaging;
pub mod kernels;
pub mod loss;
pub mod mesh;
pub mod modules;
pub mod render;
pub mod shape_buckets;
pub mod train;
