//! Volume compositing (NeRF's quadrature) as one kernel a pass on the GPU backends, where the
//! ordinary ops of [`crate::render::volume::composite`] (a running sum, exponentials, products
//! and three sums, and twice as many in the backward: about 25 launches a composite and as many
//! `[R, S]` intermediates in memory) become one launch forward and one backward.
//!
//! - [`cube`]: the forward and backward as CubeCL kernels, one unit a ray.
//! - [`op`]: a Burn op with that backward, under autodiff and Fusion.
//! - [`ragged`], [`ragged_cube`]: compositing straight from each ray's run of marched samples
//!   (no padded layout), on Flex and as CubeCL kernels.

pub mod cube;
pub mod op;
pub mod ragged;
pub mod ragged_cube;
