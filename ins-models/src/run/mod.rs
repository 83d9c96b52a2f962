//! The run layer: how a run of any variant lives, written once.
//!
//! - [`args`]: the argument groups (source, schedule, style, stylizer) every variant's config
//!   flattens into its flags and its `config.json`;
//! - [`variant`]: the [`Variant`] trait, what differs between NeRF, IDR and SIREN;
//! - [`lifecycle`]: [`train`] (pretrain or stylize into a locked run folder) and [`Run::load`];
//! - [`scene`]: a scene at a run's resolution, and the views a run evaluates on;
//! - [`scene_frame`]: the frame a run's field was trained in, written and checked;
//! - [`scene_render`]: [`SceneRender`], the one interface of a 3D run (frames, meshes);
//! - [`any`]: [`AnyRun`], any run folder loaded by the variant its `config.json` names.
//!
//! A new variant is a model, a task, a renderer and an `impl Variant`, registered in [`any`].

pub mod any;
pub mod args;
pub mod lifecycle;
pub mod scene;
pub mod scene_frame;
pub mod scene_render;
pub mod variant;

pub use any::{AnyRun, RunVariant, load_scene_run};
pub use args::{RunKind, ScheduleArgs, SourceArgs, StyleArgs, StylizerArgs};
pub use lifecycle::{Prepared, Run, prepare, train};
pub use scene_render::{MeshOptions, PathFrame, RunInfo, RunMesh, SceneRender};
pub use variant::{FinalScores, RunConfig, RunState, Start, Variant};
