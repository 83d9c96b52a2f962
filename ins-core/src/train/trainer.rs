//! The one trainer: phases of steps, each a weighted sum of loss terms minimised with Adam per
//! optimizer group; seeded, checkpointed, resumable, logged, and guarded against NaN.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use super::checkpoint::{Checkpoint, CheckpointStore, load_module_bytes, module_bytes};
use super::groups::{GroupSetting, OptimGroups, Optimizable};
use super::metrics::MetricsLog;
use super::plot::{Series, plot_losses};
use super::progress::Progress;
use super::schedule::LrSchedule;

/// One phase of training (e.g. "fit" then "stylize").
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Phase {
    /// Name shown in logs and passed to the task.
    pub name: String,
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

impl Phase {
    /// A phase with a constant learning rate and no per-group or per-term settings.
    pub fn new(name: &str, steps: usize, lr: f64) -> Self {
        Self {
            name: name.to_string(),
            steps,
            lr: LrSchedule::constant(lr),
            groups: BTreeMap::new(),
            weights: BTreeMap::new(),
        }
    }

    /// Sets the weight of a loss term.
    pub fn weight(mut self, term: &str, w: f64) -> Self {
        self.weights.insert(term.to_string(), w);
        self
    }

    /// Freezes an optimizer group.
    pub fn freeze(mut self, group: &str) -> Self {
        self.groups.insert(
            group.to_string(),
            GroupSetting {
                lr_mult: 1.0,
                frozen: true,
            },
        );
        self
    }

    /// Sets a group's learning-rate multiplier.
    pub fn lr_mult(mut self, group: &str, mult: f64) -> Self {
        let e = self.groups.entry(group.to_string()).or_default();
        e.lr_mult = mult;
        self
    }
}

/// The loss terms of one step, unweighted, plus metrics that are only logged.
#[derive(Default)]
pub struct LossTerms {
    /// Named scalar (`[1]`) terms; the trainer weights and sums them.
    pub terms: Vec<(String, Tensor<1>)>,
    /// Extra logged numbers.
    pub metrics: Vec<(String, f64)>,
    /// Logged numbers computed from a term's value once the trainer has read it (e.g. PSNR
    /// from MSE), so the task does not read the term a second time.
    pub derived: Vec<(String, String, fn(f64) -> f64)>,
}

impl LossTerms {
    /// Adds a term.
    pub fn term(mut self, name: &str, value: Tensor<1>) -> Self {
        self.terms.push((name.to_string(), value));
        self
    }

    /// Adds a logged metric.
    pub fn metric(mut self, name: &str, value: f64) -> Self {
        self.metrics.push((name.to_string(), value));
        self
    }

    /// Logs `f(value of term)` as `name`.
    pub fn metric_of(mut self, name: &str, term: &str, f: fn(f64) -> f64) -> Self {
        self.derived.push((name.to_string(), term.to_string(), f));
        self
    }
}

/// What a variant tells the trainer.
pub trait Task {
    /// The model trained.
    type Model: Optimizable;

    /// The loss terms of step `step_in_phase` of `phase`. `seed` is fixed per global step, so
    /// a resumed run draws the same batches as an uninterrupted one.
    fn losses(
        &mut self,
        model: &Self::Model,
        phase: &Phase,
        step_in_phase: usize,
        seed: u64,
    ) -> Result<LossTerms>;
}

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
    /// Continue from the newest checkpoint in `out_dir`.
    pub resume: bool,
    /// No progress bar.
    pub quiet: bool,
    /// Stop after this many steps in this process (for tests of resume); `None` runs to the end.
    pub stop_after: Option<usize>,
}

impl TrainOptions {
    /// Defaults for a run folder.
    pub fn new(out_dir: impl Into<PathBuf>) -> Self {
        Self {
            out_dir: out_dir.into(),
            seed: 0,
            checkpoint_every: 100,
            log_every: 10,
            resume: false,
            quiet: false,
            stop_after: None,
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
}

/// Runs phases of a [`Task`].
pub struct Trainer {
    phases: Vec<Phase>,
    opts: TrainOptions,
}

#[derive(Serialize, Deserialize, Default)]
struct TrainerState {
    step: usize,
    seed: u64,
    history: Vec<serde_json::Value>,
}

/// A per-step seed derived from the run seed (SplitMix64).
pub fn step_seed(seed: u64, step: usize) -> u64 {
    let mut z = seed ^ (step as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Trainer {
    /// A trainer for `phases`.
    pub fn new(phases: Vec<Phase>, opts: TrainOptions) -> Self {
        Self { phases, opts }
    }

    /// Total steps over all phases.
    pub fn total_steps(&self) -> usize {
        self.phases.iter().map(|p| p.steps).sum()
    }

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

    /// Trains `model` on `task`, resuming from the run folder's newest checkpoint if asked.
    pub fn run<T: Task>(
        &self,
        task: &mut T,
        mut model: T::Model,
    ) -> Result<TrainOutcome<T::Model>> {
        let out = &self.opts.out_dir;
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let store = CheckpointStore::new(out.join("checkpoints"), 2);
        let names = <T::Model as Optimizable>::group_names();
        let mut groups = OptimGroups::new(names);
        let mut state = TrainerState {
            seed: self.opts.seed,
            ..Default::default()
        };

        if self.opts.resume {
            match store.load_latest()? {
                Some(ckpt) => {
                    let origin = store.dir().join("latest");
                    model = load_module_bytes(model, ckpt.model, &origin)?;
                    groups.load_bytes(ckpt.optim)?;
                    state = serde_json::from_value(ckpt.state).with_context(|| {
                        format!("{}: malformed trainer state", origin.display())
                    })?;
                }
                None => bail!(
                    "--resume: no checkpoint in {} (start without --resume)",
                    store.dir().display()
                ),
            }
        } else if store.dir().join("latest").exists() {
            bail!(
                "{} already holds a run; pass --resume to continue it or choose another --out",
                out.display()
            );
        }
        // The metrics log mirrors the history up to the resumed step.
        let metrics_path = out.join("metrics.jsonl");
        std::fs::remove_file(&metrics_path).ok();
        let mut log = MetricsLog::open(&metrics_path)?;
        for rec in &state.history {
            log.write(rec)?;
        }

        let total = self.total_steps();
        let start = state.step;
        let progress = Progress::new(total, start, self.opts.quiet);
        let t0 = Instant::now();
        let mut last = BTreeMap::new();
        let mut current_phase = usize::MAX;
        let mut step = start;
        let mut run_here = 0usize;
        while step < total {
            if let Some(limit) = self.opts.stop_after
                && run_here >= limit
            {
                break;
            }
            let (pi, in_phase) = self.phase_at(step);
            let phase = &self.phases[pi];
            if pi != current_phase {
                if pi > 0 && in_phase == 0 {
                    // A new phase optimizes a new objective: its Adam moments start afresh
                    // (also when a resumed run starts exactly here).
                    groups = OptimGroups::new(names);
                }
                groups.configure(&phase.groups);
                current_phase = pi;
            }
            let ts = Instant::now();
            let terms = task.losses(&model, phase, in_phase, step_seed(state.seed, step))?;
            let mut total_loss: Option<Tensor<1>> = None;
            for (name, t) in &terms.terms {
                let w = phase.weights.get(name).copied().unwrap_or(1.0);
                if w != 0.0 {
                    let weighted = t.clone().mul_scalar(w);
                    total_loss = Some(match total_loss {
                        Some(acc) => acc + weighted,
                        None => weighted,
                    });
                }
            }
            // Every term and the total come back to the host in one read: one sync per step.
            let read: Vec<Tensor<1>> = terms
                .terms
                .iter()
                .map(|(_, t)| t.clone())
                .chain(total_loss.clone())
                .map(|t| t.detach())
                .collect();
            let values = Tensor::cat(read, 0)
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("reading the loss values: {e:?}"))?;
            let mut record = serde_json::Map::new();
            record.insert("step".into(), step.into());
            record.insert("phase".into(), phase.name.clone().into());
            for ((name, _), &value) in terms.terms.iter().zip(&values) {
                let w = phase.weights.get(name).copied().unwrap_or(1.0);
                if !value.is_finite() {
                    let good = store
                        .latest_model_path()
                        .map(|p| format!("the last good checkpoint is {}", p.display()))
                        .unwrap_or_else(|| "no checkpoint was written yet".to_string());
                    bail!(
                        "the loss diverged: term {name:?} is {value} at step {step} (phase {}); {good}. \
                         Lower the learning rate (now {:.2e}) or the weight of {name:?} ({w}), then resume with --resume.",
                        phase.name,
                        phase.lr.at(in_phase)
                    );
                }
                last.insert(name.clone(), value as f64);
                record.insert(name.clone(), (value as f64).into());
            }
            for (name, term, f) in &terms.derived {
                if let Some(i) = terms.terms.iter().position(|(n, _)| n == term) {
                    let v = f(values[i] as f64);
                    last.insert(name.clone(), v);
                    record.insert(name.clone(), v.into());
                }
            }
            for (name, v) in &terms.metrics {
                last.insert(name.clone(), *v);
                record.insert(name.clone(), (*v).into());
            }
            // Parameters that produced a finite loss are the ones checkpointed.
            if self.opts.checkpoint_every > 0
                && step > start
                && step.is_multiple_of(self.opts.checkpoint_every)
            {
                state.step = step;
                self.save(&store, &model, &groups, &state)?;
            }
            let Some(total_loss) = total_loss else {
                bail!("phase {} has no weighted loss term", phase.name);
            };
            let total_value = values[terms.terms.len()];
            if !total_value.is_finite() {
                bail!(
                    "the weighted loss is {total_value} at step {step} (phase {}) although every term is finite: \
                     a loss weight is too large for f32 ({:?})",
                    phase.name,
                    phase.weights
                );
            }
            record.insert("loss".into(), (total_value as f64).into());
            let lr = phase.lr.at(in_phase);
            let mut grads = total_loss.backward();
            model = model.optimize(&mut grads, lr, &mut groups);
            step += 1;
            run_here += 1;
            let ms = ts.elapsed().as_secs_f64() * 1e3;
            record.insert("lr".into(), lr.into());
            record.insert("ms".into(), ms.into());
            if step % self.opts.log_every.max(1) == 0 || step == total {
                let rec = serde_json::Value::Object(record);
                log.write(&rec)?;
                state.history.push(rec);
            }
            progress.update(step, status_line(&phase.name, &last));
        }
        progress.finish();
        state.step = step;
        let finished = step >= total;
        if !params_finite(&model) {
            bail!(
                "the last update made parameters non-finite at step {step}; the last good checkpoint is in {}",
                store.dir().display()
            );
        }
        self.save(&store, &model, &groups, &state)?;
        self.write_plot(&state)?;
        Ok(TrainOutcome {
            model,
            steps: step,
            finished,
            last,
            seconds: t0.elapsed().as_secs_f64(),
        })
    }

    fn save<M: Optimizable>(
        &self,
        store: &CheckpointStore,
        model: &M,
        groups: &OptimGroups,
        state: &TrainerState,
    ) -> Result<()> {
        store.save(&Checkpoint {
            step: state.step,
            model: module_bytes(model)?,
            optim: groups.to_bytes()?,
            state: serde_json::to_value(state)?,
        })?;
        Ok(())
    }

    fn write_plot(&self, state: &TrainerState) -> Result<()> {
        let mut series: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
        for rec in &state.history {
            let Some(obj) = rec.as_object() else { continue };
            let Some(step) = obj.get("step").and_then(|s| s.as_f64()) else {
                continue;
            };
            for (k, v) in obj {
                if matches!(k.as_str(), "step" | "phase" | "lr" | "ms") {
                    continue;
                }
                if let Some(v) = v.as_f64() {
                    series.entry(k.clone()).or_default().push((step, v));
                }
            }
        }
        let series: Vec<Series> = series
            .into_iter()
            .map(|(name, points)| Series { name, points })
            .collect();
        plot_losses(&series, &self.opts.out_dir.join("loss_curve.png"))
    }
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
                let bad = t.clone().is_nan().any().into_scalar::<bool>()
                    || t.is_inf().any().into_scalar::<bool>();
                self.0 = !bad;
            }
        }
    }
    let mut v = Finite(true);
    model.visit(&mut v);
    v.0
}
