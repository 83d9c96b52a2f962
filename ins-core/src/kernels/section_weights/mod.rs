//! NeuS's section weights (an SDF rendered as a volume) as one kernel forward and one backward
//! on the GPU backends. Built from Burn's ops ([`crate::render::sdf_volume::end_alpha`] and
//! [`crate::render::sdf_volume::alpha_weights`]: a sigmoid, slices, a ratio, a clamp, a log, a
//! running sum, an exponential) they take about a dozen launches forward and twice as many
//! backward, each with its `[R, S]` intermediate; IDR's volume weighs its samples three times a
//! step (two drawing rounds and the render).
//!
//! - [`cube`]: the kernels, one unit a ray.
//! - [`op`]: a Burn op with that backward, under autodiff and Fusion.

pub mod cube;
pub mod op;
