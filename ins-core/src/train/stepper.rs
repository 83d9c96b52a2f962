//! One phase's training step outside a run, taken exactly as the trainer takes it: what the
//! benchmarks time and the backends are compared on.

use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;

use super::error::TrainError;
use super::groups::ParamGroups;
use super::guard::{StepValues, weigh};
use super::phase::{Objective, Phase};
use super::task::{LossTerms, StepContext, Task};
use super::trainer::{adam, step_gradients, step_seed, update};

/// One phase's training step outside a run, exactly as the trainer takes it (the task's terms
/// weighted by the phase, backward, Adam with the phase's groups): what the benchmarks time.
pub struct Stepper<O> {
    phase: Phase<O>,
    groups: ParamGroups,
    optim: ModuleOptimizer,
    step: usize,
}

impl<O: Objective> Stepper<O> {
    /// A stepper for `phase` on `model` (its groups checked, the phase's freezing applied to the
    /// returned model), declared terms checked against `terms`.
    pub fn new<M: super::groups::Optimizable>(
        phase: Phase<O>,
        model: M,
        terms: &[&str],
    ) -> Result<(Self, M), TrainError> {
        let groups = ParamGroups::resolve(&model)?;
        phase.validate(&groups, terms)?;
        let model = groups.apply_freezing(model, &phase.groups);
        Ok((
            Self {
                phase,
                groups,
                optim: adam(),
                step: 0,
            },
            model,
        ))
    }

    /// The weighted loss of the next step of `task` on `model` and its gradients, without
    /// taking the step: what the backends are compared on, since Adam's first step
    /// (≈ lr·sign(g)) would hide an error in a gradient's scale. `None` where the step has
    /// nothing to differentiate.
    pub fn loss_and_gradients<T: Task<Objective = O>>(
        &self,
        task: &mut T,
        model: &T::Model,
    ) -> Result<(f64, Option<GradientsParams>), TrainError> {
        let ctx = standalone_context(&self.phase, self.step);
        let (mut terms, total, values) = evaluate(task, model, &ctx)?;
        let grads = step_gradients(model, &total, terms.gradients.take());
        Ok((values.total_value, grads))
    }

    /// Takes one step of `task` on `model`; returns the updated model, the weighted loss and
    /// the step's metrics (the task's, its probes' and those of its `after_step`).
    pub fn step<T: Task<Objective = O>>(
        &mut self,
        task: &mut T,
        model: T::Model,
    ) -> Result<(T::Model, f64, Vec<(String, f64)>), TrainError> {
        let ctx = standalone_context(&self.phase, self.step);
        let (mut terms, total, values) = evaluate(task, &model, &ctx)?;
        let probes = terms
            .probes
            .iter()
            .zip(&values.probes)
            .map(|(p, &v)| (p.name.to_string(), v))
            .collect();
        let (model, metrics) = self.advance(task, model, &mut terms, &total, probes)?;
        Ok((model, values.total_value, metrics))
    }

    /// Takes one step of `task` on `model` without reading its loss back (it stays on the
    /// device, as the trainer leaves it between reads off a CPU); returns the updated model and
    /// the metrics the task computed on the host.
    pub fn step_unread<T: Task<Objective = O>>(
        &mut self,
        task: &mut T,
        model: T::Model,
    ) -> Result<(T::Model, Vec<(String, f64)>), TrainError> {
        let ctx = standalone_context(&self.phase, self.step);
        let mut terms = task.losses(&model, &ctx)?;
        let total = weigh(&terms, &self.phase)?.total;
        self.advance(task, model, &mut terms, &total, Vec::new())
    }

    /// The update of a step whose terms are `terms` (weighted: `total`), then the task's
    /// `after_step`; returns the model and the metrics: the task's, `read` (values read back)
    /// and `after_step`'s.
    fn advance<T: Task<Objective = O>>(
        &mut self,
        task: &mut T,
        model: T::Model,
        terms: &mut LossTerms,
        total: &Tensor<1>,
        read: Vec<(String, f64)>,
    ) -> Result<(T::Model, Vec<(String, f64)>), TrainError> {
        let model = update(
            model,
            &mut self.optim,
            &self.groups,
            &self.phase,
            self.phase.lr.at(self.step),
            total,
            terms.gradients.take(),
        );
        let mut metrics = std::mem::take(&mut terms.metrics);
        metrics.extend(read);
        let ctx = standalone_context(&self.phase, self.step);
        metrics.extend(task.after_step(&model, &ctx)?);
        self.step += 1;
        Ok((model, metrics))
    }
}

/// Step `step` of `phase` outside a run: the run's step is the phase's, seeded as seed 0.
fn standalone_context<O>(phase: &Phase<O>, step: usize) -> StepContext<'_, O> {
    StepContext {
        phase,
        step_in_phase: step,
        global_step: step,
        seed: step_seed(0, step),
    }
}

/// The task's terms at `ctx`, their weighted total and their values, read back (a NaN stops
/// here).
fn evaluate<T: Task>(
    task: &mut T,
    model: &T::Model,
    ctx: &StepContext<T::Objective>,
) -> Result<(LossTerms, Tensor<1>, StepValues), TrainError> {
    let terms = task.losses(model, ctx)?;
    let lr = ctx.phase.lr.at(ctx.step_in_phase);
    let (total, values) = StepValues::read(&terms, ctx.phase, ctx.step_in_phase, lr, || None)?;
    Ok((terms, total, values))
}
