//! The one trainer: phases of steps, each a weighted sum of loss terms minimised with Adam;
//! optimizer groups with per-phase multipliers and freezing; seeded, checkpointed, resumable,
//! logged, plotted, and guarded against NaN.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{GradientsAccumulator, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use super::checkpoint::{Checkpoint, CheckpointStore, load_module_bytes, module_bytes};
use super::error::TrainError;
use super::folder::RunFolder;
use super::groups::ParamGroups;
use super::guard::weigh;
use super::metrics::MetricsLog;
use super::pending::{PendingSteps, READ_EVERY_ON_DEVICE};
use super::phase::{Objective, Phase};
use super::plot::plot_history;
use super::progress::{FirstStep, Progress};
use super::task::{LossTerms, StepContext, Task};
use super::watch::ProbeWatch;
use crate::kernels::adam::FusedAdam;
use crate::kernels::flex::on_flex;

/// Run-level options.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// The run folder (metrics, plot, checkpoints).
    pub out_dir: PathBuf,
    /// Seed of the run.
    pub seed: u64,
    /// Steps between checkpoints (0: only at the end).
    pub checkpoint_every: usize,
    /// Steps between metric lines.
    pub log_every: usize,
    /// Steps whose loss values are read back together (`None`: every step on a CPU, where a
    /// read costs nothing, [`READ_EVERY_ON_DEVICE`] on a GPU, where each read drains the queue).
    pub read_every: Option<usize>,
    /// Continue from the newest checkpoint in `out_dir`.
    pub resume: bool,
    /// No progress bar.
    pub quiet: bool,
    /// Stop after this many steps in this process (for tests of resume); `None` runs to the end.
    pub stop_after: Option<usize>,
    /// A wait reported until the first step ends (a first wgpu run compiles and tunes kernels
    /// for minutes before it).
    pub first_step: Option<FirstStep>,
    /// Render the held-out views once more at the end (`val/final.png`). A stylized field's
    /// take minutes on a CPU (fern's three at 504×378: 202 s); a preview leaves them out.
    pub final_pictures: bool,
}

impl TrainOptions {
    /// Defaults for a run folder.
    pub fn new(out_dir: impl Into<PathBuf>) -> Self {
        Self {
            out_dir: out_dir.into(),
            seed: 0,
            checkpoint_every: 100,
            log_every: 10,
            read_every: None,
            resume: false,
            quiet: false,
            stop_after: None,
            first_step: None,
            final_pictures: true,
        }
    }
}

/// The result of a run.
pub struct TrainOutcome<M> {
    /// The trained model.
    pub model: M,
    /// Global steps completed.
    pub steps: usize,
    /// Whether all phases finished.
    pub finished: bool,
    /// Last logged value of every term and metric.
    pub last: BTreeMap<String, f64>,
    /// Wall time of this process's training, in seconds.
    pub seconds: f64,
    /// The probes' warnings this process printed (a task's watched limits, e.g. saturation).
    pub warnings: Vec<String>,
    /// The scores of the finished run's final renders (held-out means, with how many views),
    /// empty until the run's variant fills them in.
    pub final_scores: BTreeMap<String, f64>,
}

/// Runs phases of a [`Task`].
pub struct Trainer<O> {
    phases: Vec<Phase<O>>,
    opts: TrainOptions,
}

/// What a run has logged so far: the metrics file, the probes' watch, the warnings printed, the
/// last value of every number.
struct Logbook {
    log: MetricsLog,
    watch: ProbeWatch,
    warnings: Vec<String>,
    last: BTreeMap<String, f64>,
}

/// What a checkpoint records of the trainer itself.
#[derive(Serialize, Deserialize, Default)]
struct TrainerState {
    step: usize,
    seed: u64,
    history: Vec<serde_json::Value>,
    /// The probes' runs past their limits before `step` (absent in older checkpoints).
    #[serde(default)]
    watch: ProbeWatch,
}

/// A per-step seed derived from the run seed (SplitMix64).
pub fn step_seed(seed: u64, step: usize) -> u64 {
    let mut z = seed ^ (step as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The trainer's optimizer, which the benchmarks time too: Adam (β = 0.9, 0.999; ε = 1e-8) in one
/// pass per parameter ([`FusedAdam`]).
pub fn adam() -> ModuleOptimizer {
    FusedAdam::default().init()
}

/// The trainer's Adam with the state a checkpoint's `optim.bpk` (at `path`) holds.
/// Burn's reader panics on some damaged states; that becomes an error naming the file.
pub fn restore_adam(bytes: Vec<u8>, path: &std::path::Path) -> Result<ModuleOptimizer, TrainError> {
    crate::contain::contain(|| adam().from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes)))
        .map_err(|e| TrainError::checkpoint(path, format!("damaged optimizer state: {e}")))?
        .map_err(|e| TrainError::checkpoint(path, e))
}

impl<O: Objective> Trainer<O> {
    /// A trainer for `phases`.
    pub fn new(phases: Vec<Phase<O>>, opts: TrainOptions) -> Self {
        Self { phases, opts }
    }

    /// Total steps over all phases.
    pub fn total_steps(&self) -> usize {
        self.phases.iter().map(|p| p.steps).sum()
    }

    /// The phase of global step `step` and the step within it.
    fn phase_at(&self, step: usize) -> (usize, usize) {
        let mut start = 0;
        for (i, p) in self.phases.iter().enumerate() {
            if step < start + p.steps {
                return (i, step - start);
            }
            start += p.steps;
        }
        (self.phases.len().saturating_sub(1), 0)
    }

    fn store(&self) -> CheckpointStore {
        RunFolder::new(&self.opts.out_dir).checkpoints()
    }

    /// Trains `model` on `task`, resuming from the run folder's newest checkpoint if asked.
    pub fn run<T: Task<Objective = O>>(
        &self,
        task: &mut T,
        model: T::Model,
    ) -> Result<TrainOutcome<T::Model>, TrainError> {
        let groups = ParamGroups::resolve(&model)?;
        for p in &self.phases {
            p.validate(&groups, task.terms(p.objective))?;
        }
        let out = &self.opts.out_dir;
        std::fs::create_dir_all(out).map_err(|e| TrainError::io(out, e))?;
        let store = self.store();
        let (mut model, mut optim, mut state) = self.start(&store, task, model)?;
        let log = MetricsLog::rewrite(&RunFolder::new(out).metrics(), &state.history)?;

        let total = self.total_steps();
        let start = state.step;
        let progress = Progress::new(total, start, self.opts.quiet);
        if let Some(first) = &self.opts.first_step {
            progress.attach(first);
        }
        let t0 = Instant::now();
        let mut current_phase = None;
        let mut book = Logbook {
            log,
            watch: std::mem::take(&mut state.watch),
            warnings: Vec::new(),
            last: BTreeMap::new(),
        };
        let mut pending = PendingSteps::default();
        let mut step = start;
        let stops_at =
            |step: usize| step == total || self.opts.stop_after.is_some_and(|n| step - start >= n);
        while step < total && self.opts.stop_after.is_none_or(|n| step - start < n) {
            let (pi, in_phase) = self.phase_at(step);
            let phase = &self.phases[pi];
            if current_phase != Some(pi) {
                if pi > 0 && in_phase == 0 {
                    // A new phase optimizes a new objective: its Adam moments start afresh
                    // (also when a resumed run starts exactly here).
                    optim = adam();
                }
                model = groups.apply_freezing(model, &phase.groups);
                current_phase = Some(pi);
                if pi > 0 || in_phase > 0 {
                    progress.println(format!("phase {}: {} steps", phase.name, phase.steps));
                }
            }
            let ctx = StepContext {
                phase,
                step_in_phase: in_phase,
                global_step: step,
                seed: step_seed(state.seed, step),
            };
            let lr = phase.lr.at(in_phase);
            let ts = Instant::now();
            // The task's state and the probes' watch before this step belong with the
            // parameters before it: the steps before it are read and logged first.
            let due = self.opts.checkpoint_every > 0
                && step > start
                && step.is_multiple_of(self.opts.checkpoint_every);
            let before = if due {
                self.flush(&mut pending, &store, &mut book, &mut state, &progress)?;
                Some((task.save_state()?, book.watch.clone()))
            } else {
                None
            };
            let mut terms = task.losses(&model, &ctx)?;
            check_declared(&terms, phase, task.terms(phase.objective))?;
            let weighed = weigh(&terms, phase)?;
            let read_every = self.opts.read_every.unwrap_or(if on_flex(&weighed.total) {
                1
            } else {
                READ_EVERY_ON_DEVICE
            });
            pending.push(step, pi, lr, &mut terms, weighed.values);
            // Parameters that produced a finite loss are the ones checkpointed.
            if let Some((task_state, watch_state)) = before {
                pending.read(&self.phases, || store.latest_path())?;
                state.step = step;
                state.watch = watch_state;
                self.save(&store, &model, &optim, &state, task_state)?;
                self.write_plot(&state, task);
            }
            // A loss no parameter reaches (an IDR patch whose rays all missed the surface) has
            // nothing to teach: the step is logged and the parameters and Adam stay as they are.
            let deferred = terms.gradients.take();
            model = update(
                model,
                &mut optim,
                &groups,
                phase,
                lr,
                &weighed.total,
                deferred,
            );
            if let Some(first) = &self.opts.first_step {
                first.done();
            }
            let extra = task.after_step(&model, &ctx)?;
            let has_extra = !extra.is_empty();
            pending.finish_last(ts.elapsed().as_secs_f64() * 1e3, extra);
            step += 1;
            if pending.len() >= read_every || has_extra || stops_at(step) {
                self.flush(&mut pending, &store, &mut book, &mut state, &progress)?;
            }
            progress.update(step, status_line(&phase.name, &book.last));
        }
        progress.finish();
        if let Some(first) = &self.opts.first_step {
            first.done();
        }
        state.step = step;
        state.watch = book.watch;
        if !params_finite(&model) {
            return Err(TrainError::NonFiniteParameters {
                step,
                checkpoint: store.latest_path(),
            });
        }
        self.save(&store, &model, &optim, &state, task.save_state()?)?;
        self.write_plot(&state, task);
        Ok(TrainOutcome {
            model,
            steps: step,
            finished: step >= total,
            last: book.last,
            seconds: t0.elapsed().as_secs_f64(),
            warnings: book.warnings,
            final_scores: BTreeMap::new(),
        })
    }

    /// Reads and empties `pending`: each step's probes watched, its values noted, its metrics
    /// line written (every `log_every`-th step, the last, and those with numbers of their own),
    /// its warnings printed; then the error of a step that diverged, if one did.
    fn flush(
        &self,
        pending: &mut PendingSteps,
        store: &CheckpointStore,
        book: &mut Logbook,
        state: &mut TrainerState,
        progress: &Progress,
    ) -> Result<(), TrainError> {
        let drained = pending.drain(
            &self.phases,
            || store.latest_path(),
            &mut book.watch,
            &mut book.last,
        );
        let total = self.total_steps();
        for l in drained.logged {
            for w in l.warnings {
                progress.warn(&w);
                book.warnings.push(w);
            }
            let after = l.step + 1;
            if after.is_multiple_of(self.opts.log_every.max(1)) || after == total || l.has_extra {
                let rec = serde_json::Value::Object(l.record);
                book.log.write(&rec)?;
                state.history.push(rec);
            }
        }
        drained.error.map_or(Ok(()), Err)
    }

    /// A fresh start (refusing to overwrite a run) or the state of the newest checkpoint.
    fn start<T: Task<Objective = O>>(
        &self,
        store: &CheckpointStore,
        task: &mut T,
        model: T::Model,
    ) -> Result<(T::Model, ModuleOptimizer, TrainerState), TrainError> {
        let fresh = TrainerState {
            seed: self.opts.seed,
            ..Default::default()
        };
        if !self.opts.resume {
            if store.is_started() {
                return Err(TrainError::RunExists {
                    dir: self.opts.out_dir.clone(),
                });
            }
            return Ok((model, adam(), fresh));
        }
        let Some(dir) = store.latest_dir()? else {
            return Err(TrainError::NothingToResume {
                dir: store.dir().to_path_buf(),
            });
        };
        let ckpt = CheckpointStore::load_dir(&dir)?;
        let model = load_module_bytes(model, ckpt.model, &dir.join("model.bpk"))?;
        let optim = restore_adam(ckpt.optim, &dir.join("optim.bpk"))?;
        let state: TrainerState = serde_json::from_value(ckpt.state)
            .map_err(|e| TrainError::checkpoint(dir.join("state.json"), e))?;
        if let Some(bytes) = ckpt.task {
            task.load_state(&bytes)
                .map_err(|e| TrainError::checkpoint(dir.join("task.bin"), format!("{e:#}")))?;
        }
        Ok((model, optim, state))
    }

    fn save<M: Module>(
        &self,
        store: &CheckpointStore,
        model: &M,
        optim: &ModuleOptimizer,
        state: &TrainerState,
        task: Option<Vec<u8>>,
    ) -> Result<(), TrainError> {
        let optim = optim
            .into_bytes()
            .map_err(|e| TrainError::checkpoint(store.dir(), format!("serializing Adam: {e}")))?;
        store.save(&Checkpoint {
            step: state.step,
            model: module_bytes(model)?,
            optim: optim.to_vec(),
            state: serde_json::to_value(state)
                .map_err(|e| TrainError::checkpoint(store.dir(), e))?,
            task,
        })?;
        Ok(())
    }

    /// Redraws `loss_curve.png`. A plot that cannot be drawn is reported, not fatal.
    fn write_plot<T: Task<Objective = O>>(&self, state: &TrainerState, task: &T) {
        let path = RunFolder::new(&self.opts.out_dir).loss_curve();
        let mut terms: Vec<&str> = Vec::new();
        for phase in &self.phases {
            terms.extend_from_slice(task.terms(phase.objective));
        }
        if let Err(e) = plot_history(&state.history, &terms, &path) {
            eprintln!("warning: could not draw {}: {e:#}", path.display());
        }
    }

    /// The run folder.
    pub fn out_dir(&self) -> &Path {
        &self.opts.out_dir
    }
}

/// The gradients of a step: its weighted total back-propagated, plus those the task took
/// itself (`deferred`). `None` for a total no parameter reaches (an IDR patch whose rays all
/// missed the surface) with none taken by the task: such a step has nothing to teach.
pub(super) fn step_gradients<M: Module>(
    model: &M,
    total: &Tensor<1>,
    deferred: Option<GradientsParams>,
) -> Option<GradientsParams> {
    let direct = || GradientsParams::from_grads(total.clone().backward(), model);
    match (total.is_tracked(), deferred) {
        (false, None) => None,
        (true, None) => Some(direct()),
        (false, Some(deferred)) => Some(deferred),
        (true, Some(deferred)) => {
            let mut sum = GradientsAccumulator::<M>::new();
            sum.accumulate(model, deferred);
            sum.accumulate(model, direct());
            Some(sum.grads())
        }
    }
}

/// Takes the Adam step of a step's [`step_gradients`] with the phase's learning rates; where
/// there are none, the parameters and Adam stay as they are.
pub(super) fn update<M: Module>(
    model: M,
    optim: &mut ModuleOptimizer,
    groups: &ParamGroups,
    phase: &Phase<impl Objective>,
    lr: f64,
    total: &Tensor<1>,
    deferred: Option<GradientsParams>,
) -> M {
    match step_gradients(&model, total, deferred) {
        Some(grads) => optim.step(groups.learning_rates(lr, &phase.groups), model, grads),
        None => model,
    }
}

/// A task must return only the terms it declares for the objective.
fn check_declared<O>(
    terms: &LossTerms,
    phase: &Phase<O>,
    declared: &[&str],
) -> Result<(), TrainError> {
    for (name, _) in &terms.terms {
        if !declared.contains(name) {
            return Err(TrainError::UndeclaredTerm {
                phase: phase.name.clone(),
                term: name.to_string(),
                known: declared.join(", "),
            });
        }
    }
    Ok(())
}

fn status_line(phase: &str, last: &BTreeMap<String, f64>) -> String {
    let mut s = phase.to_string();
    for (k, v) in last {
        s.push_str(&format!(" {k}={v:.3e}"));
    }
    s
}

/// True if every float parameter of `model` is finite.
pub fn params_finite<M: Module>(model: &M) -> bool {
    struct Finite(bool);
    impl ModuleVisitor for Finite {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if self.0 {
                let t = param.val();
                self.0 = t.is_finite().all().into_scalar::<bool>();
            }
        }
    }
    let mut v = Finite(true);
    model.visit(&mut v);
    v.0
}
