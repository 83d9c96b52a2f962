//! Rendering along rays: samplers (stratified, hierarchical, occupancy-grid marching), volume
//! compositing, signed distance fields as volumes (NeuS) and their sphere tracing. Cameras,
//! rays and patches come from `ins-scene`, in its one camera convention.

pub mod beyond_sphere;
mod empty_blocks;
pub mod flagged_picks;
pub mod gather;
pub mod marched_layout;
pub mod marched_samples;
pub mod merge_rows;
pub mod occupancy;
mod occupancy_march;
pub mod samplers;
pub mod sdf_volume;
pub mod sphere_tracing;
pub mod volume;
