//! The ray samplers as kernels on the GPU backends, with their jitter made where it is used
//! ([`super::jitter`]). Built from Burn's ops ([`crate::render::samplers`] on flex), NeRF's
//! hierarchical draws take about twenty launches a call and compare every draw with every CDF
//! edge, an `[R, n, S]` intermediate (75 M entries for 9,216 rays, 128 draws and 64 samples);
//! a unit per ray walks its CDF once for all its draws, which come in increasing order. The
//! stratified samples are one launch instead of an upload of host-drawn numbers and four.
//!
//! - [`cube`]: the kernels.
//! - [`op`]: Burn ops under autodiff and Fusion (no gradient: samples are positions).

pub mod cube;
pub mod op;
