//! NeRF + INS: stylized novel-view synthesis. A radiance field is pretrained on posed photos
//! (photometric MSE), then stylized through SIM + AM with VGG style and content losses on
//! strided patches, while a frozen copy of the pretrained geometry keeps the density in place
//! (the self-distilled geometry loss).
//!
//! - [`model`]: the field (hash grid or NeRF MLP), coarse field, SIM and AM composed.
//! - [`render`]: sampling along rays, evaluating the field under every style, compositing.
//! - [`task`]: the losses of each phase, occupancy refresh, held-out evaluation.
//! - [`background`]: the background colour an unbounded capture learns.
//! - [`deferred`]: large stylization patches back-propagated chunk by chunk (ARF's deferred
//!   back-propagation).
//! - [`run`]: the NeRF variant of the shared run layer (pretrain, stylize, load).
//! - [`eval`]: whole-view renders and their PSNR / SSIM.
//! - [`mesh`]: marching cubes of the density, coloured by the radiance.
//! - [`scene_render`]: a NeRF run as the shared 3D interface (frames, meshes).

pub mod background;
pub mod config;
pub mod deferred;
pub mod early_stop;
pub mod eval;
pub mod mesh;
pub mod model;
pub mod render;
pub mod run;
pub mod scene_render;
pub mod state_io;
pub mod task;
#[cfg(test)]
mod test_models;
pub mod view_audit;

pub use config::NerfRunConfig;
pub use model::NerfModel;
pub use run::{Nerf, NerfRun};
