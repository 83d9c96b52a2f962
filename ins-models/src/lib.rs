//! INS variants. Each composes the shared SIM / CIM / AM modules of `ins-core` and says how a
//! batch is rendered and which loss terms train it; the trainer, losses and checkpoints are
//! shared.
//!
//! - [`siren`]: SIREN + INS, stylizing a 2D image through its implicit representation.
//! - [`nerf`]: NeRF + INS, stylized radiance fields from posed photos.
//! - [`idr`]: IDR + INS, stylized implicit surfaces from masked multi-view photos.
//! - [`image_task`]: the image-fitting and stylization task any coordinate → RGB model uses
//!   (SIREN, or a user's own content module).
//! - [`stylize2d`]: classic 2D style transfer of one image, and the per-view baseline.
//! - [`consistency`]: a stylized 3D run evaluated along a camera path.
//! - [`mesh_export`]: a 3D run's surface as PLY or glTF; [`mesh_score`]: that surface against a
//!   reference (Chamfer distance, F-score); [`video`]: frames as GIF, MP4 or PNGs.

// Burn's `slice` takes one range per dimension, so `[a..b]` on a 1-D tensor is the idiom.
#![allow(clippy::single_range_in_vec_init)]

pub mod config;
pub mod consistency;
pub mod demo;
pub mod idr;
pub mod image_task;
pub mod mesh_export;
pub mod mesh_score;
pub mod nerf;
pub mod run;
pub mod siren;
pub mod style_mix;
pub mod stylize2d;
pub mod video;
