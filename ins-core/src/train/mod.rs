//! The one trainer every variant uses: optimizer groups, schedules, phases, checkpoints,
//! metrics and progress.

pub mod checkpoint;
pub mod groups;
pub mod metrics;
pub mod plot;
pub mod progress;
pub mod schedule;
pub mod seeding;
pub mod trainer;

pub use trainer::{LossTerms, Phase, Task, TrainOptions, TrainOutcome, Trainer};
