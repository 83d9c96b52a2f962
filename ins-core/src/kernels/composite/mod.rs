//! Volume compositing (NeRF's quadrature) as backend operations: one walk a ray forward, two
//! backward, where Burn's ordinary ops (a running sum, exponentials, products and three sums,
//! and twice as many in the backward) took about 25 launches a composite on a GPU and as many
//! intermediates in memory.
//!
//! - [`ragged`]: the op over each ray's run of samples, under autodiff and Fusion, and its
//!   Flex implementation.
//! - [`ragged_cube`]: its CubeCL kernels, one unit a ray.

pub mod ragged;
pub mod ragged_cube;
