//! The one trainer every variant uses: optimizer groups, schedules, phases, checkpoints,
//! metrics, plots and progress.

pub mod checkpoint;
pub mod error;
pub mod folder;
pub mod groups;
pub mod guard;
pub mod metrics;
mod pending;
pub mod phase;
pub mod plot;
pub mod progress;
pub mod schedule;
pub mod seeding;
pub mod stepper;
pub mod task;
pub mod trainer;
pub mod watch;

pub use error::TrainError;
pub use folder::{RunFolder, RunLock};
pub use groups::{GroupSetting, GroupSpec, Optimizable, ParamGroups};
pub use phase::{Objective, Phase};
pub use schedule::LrSchedule;
pub use stepper::Stepper;
pub use task::{LossTerms, Probe, StepContext, Task, Watch};
pub use trainer::{TrainOptions, TrainOutcome, Trainer, adam, step_seed};
