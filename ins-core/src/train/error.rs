//! What can stop a run, as types a caller can match on. Each message names the thing at fault
//! (the term, the group, the parameter, the file) and says what to do next.

use std::path::PathBuf;

/// Why a run did not start or did not finish.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A loss term became NaN or infinite.
    #[error(
        "the loss diverged: term {term:?} is {value} at step {step} (phase {phase}); {}. \
         Lower the learning rate (now {lr:.2e}) or the weight of {term:?} ({weight}), then resume with --resume.",
        checkpoint_note(checkpoint)
    )]
    Diverged {
        /// The loss term.
        term: String,
        /// Its value (NaN or ±inf).
        value: f32,
        /// Global step.
        step: usize,
        /// Phase name.
        phase: String,
        /// Learning rate of that step.
        lr: f64,
        /// Weight of the term.
        weight: f64,
        /// The last complete checkpoint, if any.
        checkpoint: Option<PathBuf>,
    },
    /// Every term is finite but their weighted sum overflows f32.
    #[error(
        "the weighted loss is {value} at step {step} (phase {phase}) although every term is finite: \
         a loss weight is too large for f32 ({weights})"
    )]
    WeightOverflow {
        /// The sum.
        value: f32,
        /// Global step.
        step: usize,
        /// Phase name.
        phase: String,
        /// The phase's weights, for the message.
        weights: String,
    },
    /// An update made parameters non-finite although the loss was finite.
    #[error(
        "the last update made parameters non-finite at step {step}; {}",
        checkpoint_note(checkpoint)
    )]
    NonFiniteParameters {
        /// Global step.
        step: usize,
        /// The last complete checkpoint, if any.
        checkpoint: Option<PathBuf>,
    },
    /// A trainable parameter belongs to no optimizer group, so it would never be trained.
    #[error(
        "parameter {path} belongs to no optimizer group (groups: {known}); add its module to a group of the model"
    )]
    UngroupedParameter {
        /// Module path of the parameter.
        path: String,
        /// The model's groups.
        known: String,
    },
    /// A parameter matches several groups, so its learning rate and freezing are ambiguous.
    #[error(
        "parameter {path} belongs to optimizer groups {first:?} and {second:?}; each parameter must be in exactly one"
    )]
    AmbiguousParameter {
        /// Module path of the parameter.
        path: String,
        /// One group.
        first: String,
        /// Another group.
        second: String,
    },
    /// A group of the model covers no parameter (a misspelt module path).
    #[error("optimizer group {group:?} covers no parameter of the model (paths {paths:?})")]
    EmptyGroup {
        /// The group.
        group: String,
        /// The path prefixes it was declared with.
        paths: Vec<String>,
    },
    /// A phase configures a group the model does not have.
    #[error(
        "phase {phase:?} configures optimizer group {group:?}, which the model does not have (groups: {known})"
    )]
    UnknownGroup {
        /// The phase.
        phase: String,
        /// The group it names.
        group: String,
        /// The model's groups.
        known: String,
    },
    /// A phase weights a loss term its objective does not produce.
    #[error(
        "phase {phase:?} weights loss term {term:?}, which its objective does not produce (terms: {known})"
    )]
    UnknownTerm {
        /// The phase.
        phase: String,
        /// The term it names.
        term: String,
        /// The terms of the objective.
        known: String,
    },
    /// A task returned a term it did not declare for the phase's objective.
    #[error(
        "the task returned loss term {term:?} in phase {phase:?}, which it does not declare (declared: {known})"
    )]
    UndeclaredTerm {
        /// The phase.
        phase: String,
        /// The term.
        term: String,
        /// The declared terms.
        known: String,
    },
    /// No term of a phase has a non-zero weight.
    #[error("phase {phase:?} has no loss term with a non-zero weight")]
    NothingToMinimise {
        /// The phase.
        phase: String,
    },
    /// The run folder already holds a run.
    #[error("{} already holds a run; pass --resume to continue it or choose another --out", dir.display())]
    RunExists {
        /// The run folder.
        dir: PathBuf,
    },
    /// Another process is training into the run folder.
    #[error(
        "{} is in use by another run (pid {pid}); wait for it to finish or choose another --out",
        dir.display()
    )]
    RunInUse {
        /// The run folder.
        dir: PathBuf,
        /// The process holding its lock, as written in `run.lock`.
        pid: String,
    },
    /// A checkpoint could not be written (a full disk, a file-size limit).
    #[error(
        "writing the checkpoint of step {step} failed: {source}; {}. Free space (or raise the limit), then continue with --resume",
        checkpoint_note(last_good)
    )]
    CheckpointWrite {
        /// Global step of the checkpoint.
        step: usize,
        /// The failure, naming the file.
        source: ins_io::IoError,
        /// The newest complete checkpoint, untouched.
        last_good: Option<PathBuf>,
    },
    /// `--resume` without a checkpoint.
    #[error("--resume: no checkpoint in {} (start without --resume)", dir.display())]
    NothingToResume {
        /// The checkpoint folder.
        dir: PathBuf,
    },
    /// A checkpoint that cannot be read or does not fit the model.
    #[error("{}: {reason}", path.display())]
    Checkpoint {
        /// The file or folder.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A file could not be written or read.
    #[error(transparent)]
    Io(#[from] ins_io::IoError),
    /// The task failed (data, rendering, evaluation).
    #[error(transparent)]
    Task(#[from] anyhow::Error),
}

fn checkpoint_note(checkpoint: &Option<PathBuf>) -> String {
    match checkpoint {
        Some(p) => format!("the last good checkpoint is {}", p.display()),
        None => "no checkpoint was written yet".to_string(),
    }
}

impl TrainError {
    pub(crate) fn checkpoint(path: impl Into<PathBuf>, reason: impl std::fmt::Display) -> Self {
        TrainError::Checkpoint {
            path: path.into(),
            reason: reason.to_string(),
        }
    }

    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        TrainError::Io(ins_io::IoError {
            path: path.to_path_buf(),
            source,
        })
    }
}
