//! NeRF's hierarchical draws (the inverse CDF of a ray's coarse weights) as one kernel on the GPU
//! backends. Built from Burn's ops ([`crate::render::samplers::draw_from_weights`] on flex) they
//! take about twenty launches a call and compare every draw with every CDF edge, an
//! `[R, n, S]` intermediate (75 M entries for 9,216 rays, 128 draws and 64 samples); a unit per
//! ray walks its CDF once for all its draws, which come in increasing order.
//!
//! - [`cube`]: the kernel.
//! - [`op`]: a Burn op under autodiff and Fusion (no gradient: the draws are positions).

pub mod cube;
pub mod op;
