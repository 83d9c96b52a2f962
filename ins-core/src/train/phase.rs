//! A phase of training: an objective (what the task computes), a number of steps, a learning
//! rate schedule, per-group settings and per-term weights.
//!
//! The objective is a value of the task's own type (an enum such as `Fit` / `Stylize`), so a
//! task chooses what to compute by matching on it, never by comparing a phase's name.

use std::collections::BTreeMap;
use std::fmt::Debug;

use serde::{Deserialize, Serialize};

use super::error::TrainError;
use super::groups::{GroupSetting, ParamGroups};
use super::schedule::LrSchedule;

/// What a task's phase objectives must be: small values that serialize into configs.
pub trait Objective: Copy + PartialEq + Debug + Send + Sync + 'static {}
impl<T: Copy + PartialEq + Debug + Send + Sync + 'static> Objective for T {}

/// One phase of training (e.g. fitting, then stylizing).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Phase<O> {
    /// Name shown in logs, metrics and the loss plot.
    pub name: String,
    /// What the task computes in this phase.
    pub objective: O,
    /// Number of steps.
    pub steps: usize,
    /// Learning-rate schedule, restarted at the phase's first step.
    pub lr: LrSchedule,
    /// Multiplier and freezing per optimizer group (missing: ×1, trained).
    #[serde(default)]
    pub groups: BTreeMap<String, GroupSetting>,
    /// Weight per loss term (missing: 1).
    #[serde(default)]
    pub weights: BTreeMap<String, f64>,
}

impl<O: Objective> Phase<O> {
    /// A phase with a constant learning rate and no per-group or per-term settings.
    pub fn new(name: &str, objective: O, steps: usize, lr: f64) -> Self {
        Self {
            name: name.to_string(),
            objective,
            steps,
            lr: LrSchedule::constant(lr),
            groups: BTreeMap::new(),
            weights: BTreeMap::new(),
        }
    }

    /// Sets the learning-rate schedule.
    pub fn schedule(mut self, lr: LrSchedule) -> Self {
        self.lr = lr;
        self
    }

    /// Sets the weight of a loss term.
    pub fn weight(mut self, term: &str, w: f64) -> Self {
        self.weights.insert(term.to_string(), w);
        self
    }

    /// Freezes an optimizer group: its parameters get no gradients and do not move.
    pub fn freeze(mut self, group: &str) -> Self {
        self.groups.entry(group.to_string()).or_default().frozen = true;
        self
    }

    /// Sets a group's learning-rate multiplier.
    pub fn lr_mult(mut self, group: &str, mult: f64) -> Self {
        self.groups.entry(group.to_string()).or_default().lr_mult = mult;
        self
    }
}

impl<O> Phase<O> {
    /// Weight of a term (1 when not set).
    pub fn weight_of(&self, term: &str) -> f64 {
        self.weights.get(term).copied().unwrap_or(1.0)
    }

    /// Checks the phase against the model's groups and the terms its objective produces:
    /// unknown group names and weights of terms that do not exist are errors.
    pub fn validate(&self, groups: &ParamGroups, terms: &[&str]) -> Result<(), TrainError> {
        for g in self.groups.keys() {
            if !groups.contains(g) {
                return Err(TrainError::UnknownGroup {
                    phase: self.name.clone(),
                    group: g.clone(),
                    known: groups.known(),
                });
            }
        }
        for t in self.weights.keys() {
            if !terms.contains(&t.as_str()) {
                return Err(TrainError::UnknownTerm {
                    phase: self.name.clone(),
                    term: t.clone(),
                    known: terms.join(", "),
                });
            }
        }
        if !terms.iter().any(|t| self.weight_of(t) != 0.0) {
            return Err(TrainError::NothingToMinimise {
                phase: self.name.clone(),
            });
        }
        Ok(())
    }
}
