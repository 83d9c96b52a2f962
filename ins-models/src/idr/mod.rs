//! IDR + INS: stylized implicit surfaces. A signed distance field and a rendering network are
//! learned from masked multi-view photos (DTU) with IDR's losses; stylization then trains SIM +
//! AM inside the rendering network with VGG losses on strided patches inside the mask, the
//! surface kept (its learning rate scaled down, by default frozen).
//!
//! - [`model`]: SDF network (IDR MLP or hash grid), rendering network, SIM and AM.
//! - [`render`]: sphere tracing and IDR's differentiable surface point.
//! - [`volume`]: the SDF rendered as a volume (NeuS), the other way to pretrain;
//!   [`volume_view`]: whole views rendered that way, the clear rays skipped.
//! - [`task`]: the losses ([`smoothness`]: the volume's curvature term);
//!   [`run`]: pretraining, stylizing, loading runs.
//! - [`eval`]: silhouette IoU and PSNR inside the mask; [`mesh`]: marching-cubes export.
//! - [`scene_render`]: an IDR run as the shared 3D interface (frames, meshes).

pub mod config;
pub mod eval;
pub mod mesh;
pub mod model;
pub mod render;
pub mod run;
pub mod scene_render;
pub mod smoothness;
pub mod task;
pub mod volume;
pub mod volume_view;

pub use config::IdrRunConfig;
pub use model::IdrModel;
pub use run::{Idr, IdrRun};
