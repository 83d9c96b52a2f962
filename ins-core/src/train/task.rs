//! What a variant tells the trainer: the loss terms of a step, for the phase's objective.

use anyhow::Result;
use burn::optim::GradientsParams;
use burn::prelude::*;

use super::groups::Optimizable;
use super::phase::{Objective, Phase};

/// Where a step stands: its phase, its position and its seed.
#[derive(Debug, Clone, Copy)]
pub struct StepContext<'a, O> {
    /// The phase (its objective says what to compute).
    pub phase: &'a Phase<O>,
    /// Step within the phase, from 0.
    pub step_in_phase: usize,
    /// Step of the whole run, from 0.
    pub global_step: usize,
    /// Seed of this step, fixed per global step: a resumed run draws the same batches.
    pub seed: u64,
}

/// The loss terms of one step, unweighted, plus numbers that are only logged.
#[derive(Default)]
pub struct LossTerms {
    /// Named scalar (`[1]`) terms; the trainer weights and sums them.
    pub terms: Vec<(&'static str, Tensor<1>)>,
    /// Extra logged numbers.
    pub metrics: Vec<(String, f64)>,
    /// Numbers computed on the device, read with the terms in their one transfer and logged;
    /// the trainer warns when a watched one stays past its limit.
    pub probes: Vec<Probe>,
    /// Logged numbers computed from a term's value once the trainer has read it (e.g. PSNR
    /// from MSE), so the task does not read the term a second time.
    pub derived: Vec<Derived>,
    /// Parameter gradients the task back-propagated itself, in pieces (deferred
    /// back-propagation): the trainer adds those of the weighted terms still tracked (none, if
    /// the task gave their values only) and steps with the sum.
    pub gradients: Option<GradientsParams>,
}

/// A logged number derived from a term: (its name, the term's name, the function of the
/// term's value).
pub type Derived = (&'static str, &'static str, fn(f64) -> f64);

impl LossTerms {
    /// Adds a term.
    pub fn term(mut self, name: &'static str, value: Tensor<1>) -> Self {
        self.terms.push((name, value));
        self
    }

    /// Sets the gradients the task took itself (see [`LossTerms::gradients`]).
    pub fn with_gradients(mut self, gradients: GradientsParams) -> Self {
        self.gradients = Some(gradients);
        self
    }

    /// Adds a probe (see [`LossTerms::probes`]).
    pub fn probe(mut self, probe: Probe) -> Self {
        self.probes.push(probe);
        self
    }

    /// Adds a logged metric.
    pub fn metric(mut self, name: &str, value: f64) -> Self {
        self.metrics.push((name.to_string(), value));
        self
    }

    /// Logs `f(value of term)` as `name`.
    pub fn metric_of(mut self, name: &'static str, term: &'static str, f: fn(f64) -> f64) -> Self {
        self.derived.push((name, term, f));
        self
    }
}

/// A number of the step computed on the device (`[1]`, detached), logged under `name`.
pub struct Probe {
    /// Its name in the metrics.
    pub name: &'static str,
    /// Its value, `[1]`.
    pub value: Tensor<1>,
    /// When the trainer should warn about it.
    pub watch: Option<Watch>,
}

/// A probe's limit: above `limit` for `steps` steps in a row, the trainer prints `warning` once
/// (with the step and the value) and goes on: the run may still be what the user wants.
#[derive(Debug, Clone)]
pub struct Watch {
    /// The value above which a step counts.
    pub limit: f64,
    /// How many steps in a row make the warning.
    pub steps: usize,
    /// What it means and what to do, in a sentence or two.
    pub warning: String,
}

/// A training task: a model, the terms each objective produces, and how to compute them.
pub trait Task {
    /// The model trained.
    type Model: Optimizable;
    /// What a phase asks for (e.g. an enum `Fit` / `Stylize`).
    type Objective: Objective;

    /// The loss terms an objective produces. Phases may weight only these.
    fn terms(&self, objective: Self::Objective) -> &'static [&'static str];

    /// The loss terms of one step.
    fn losses(
        &mut self,
        model: &Self::Model,
        step: &StepContext<Self::Objective>,
    ) -> Result<LossTerms>;

    /// Runs after the optimizer step (refresh caches that depend on the model, evaluate on
    /// held-out data); returns numbers to log for this step.
    fn after_step(
        &mut self,
        _model: &Self::Model,
        _step: &StepContext<Self::Objective>,
    ) -> Result<Vec<(String, f64)>> {
        Ok(Vec::new())
    }

    /// State of the task that a resumed run needs to continue exactly (e.g. an occupancy grid
    /// built from past steps); saved in every checkpoint. It must only change in
    /// [`Task::after_step`].
    fn save_state(&self) -> Result<Option<Vec<u8>>> {
        Ok(None)
    }

    /// Restores what [`Task::save_state`] wrote.
    fn load_state(&mut self, _bytes: &[u8]) -> Result<()> {
        Ok(())
    }
}
