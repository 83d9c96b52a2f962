//! Rendering along rays: samplers (stratified, hierarchical, occupancy-grid marching), volume
//! compositing, and sphere tracing of signed distance fields. Cameras, rays and patches come
//! from `ins-scene`, in its one camera convention.

pub mod gather;
pub mod occupancy;
pub mod samplers;
pub mod sphere_tracing;
pub mod volume;
