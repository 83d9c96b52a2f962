//! The run layer: how a run of any variant lives, written once.
//!
//! - [`args`]: the argument groups (source, schedule, style, stylizer) every variant's config
//!   flattens into its flags and its `config.json`;
//! - [`variant`]: the [`Variant`] trait, what differs between NeRF, IDR and SIREN;
//! - [`lifecycle`]: [`train`] (pretrain or stylize into a locked run folder) and [`Run::load`];
//! - [`scene`]: a scene at a run's resolution, and the views a run evaluates on.
//!
//! A new variant is a model, a task, a renderer and an `impl Variant`.

pub mod args;
pub mod lifecycle;
pub mod scene;
pub mod scene_frame;
pub mod variant;

pub use args::{RunKind, ScheduleArgs, SourceArgs, StyleArgs, StylizerArgs};
pub use lifecycle::{Prepared, Run, prepare, train};
pub use variant::{Start, Variant};
