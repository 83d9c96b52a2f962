//! The multiresolution hash encoding's maths (the module is `crate::modules::hash_grid`).
//!
//! - [`kernel`]: the maths on slices (forward, both backwards, the spatial Jacobian).
//! - [`avx512`], [`avx2`]: the lookup, the Jacobian and their table gradients 16 or 8 points
//!   at a time where the CPU allows, bit-identical to `kernel`'s loops; [`vector`] picks.
//! - [`cube`]: the same maths as CubeCL kernels for the GPU backends (device code in
//!   `cube_kernels`).
//! - [`op`]: a Burn op with a hand-written backward that runs the kernels on Flex and
//!   the CubeCL backends.
//! - [`reference`]: the same function from ordinary Burn ops (the tests' yardstick, and any
//!   backend without the op).

pub mod avx2;
pub mod avx512;
pub mod cube;
mod cube_kernels;
pub mod kernel;
pub mod op;
pub mod reference;
pub mod vector;

pub use kernel::GridShape;
