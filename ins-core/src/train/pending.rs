//! Steps whose loss values are still on the device. On a GPU every read-back drains the queue
//! and leaves the device idle while the host prepares the next step, so the trainer reads the
//! values of several steps in one transfer; on a CPU a read costs nothing and every step is
//! read at once (the divergence guard stops at the step that diverged either way, and a
//! checkpoint is only written once its step's values are read and finite).

use std::collections::BTreeMap;

use burn::prelude::*;

use super::error::TrainError;
use super::guard::{StepValues, read_back};
use super::phase::Phase;
use super::task::{Derived, LossTerms, Probe};
use super::watch::ProbeWatch;

/// Steps between reads of the loss values off a CPU (also the default log interval).
pub const READ_EVERY_ON_DEVICE: usize = 10;

/// One step as logged, its values read or still on the device.
struct PendingStep {
    step: usize,
    phase: usize,
    lr: f64,
    names: Vec<&'static str>,
    derived: Vec<Derived>,
    metrics: Vec<(String, f64)>,
    probes: Vec<Probe>,
    on_device: Option<Tensor<1>>,
    read: Option<Vec<f32>>,
    ms: f64,
    extra: Vec<(String, f64)>,
}

/// The steps taken since the last read, in order.
#[derive(Default)]
pub(super) struct PendingSteps {
    steps: Vec<PendingStep>,
}

/// The steps of a drained queue: those read and logged in order, and the error of the first
/// that diverged, if one did (the steps after it are dropped).
pub(super) struct Drained {
    /// The steps before any that diverged.
    pub logged: Vec<Logged>,
    /// The divergence, or a failed read.
    pub error: Option<TrainError>,
}

/// What a drained step adds to the run's records.
pub(super) struct Logged {
    /// Its global step.
    pub step: usize,
    /// Its metrics line.
    pub record: serde_json::Map<String, serde_json::Value>,
    /// Whether it carried numbers of its own (`after_step`'s evaluations): always logged.
    pub has_extra: bool,
    /// The probes' warnings at this step.
    pub warnings: Vec<String>,
}

impl PendingSteps {
    /// Steps waiting.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// Adds step `step` (of phase `phase`, at learning rate `lr`): its terms' names, metrics and
    /// probes move here, its values stay on the device until [`PendingSteps::read`].
    pub fn push(
        &mut self,
        step: usize,
        phase: usize,
        lr: f64,
        terms: &mut LossTerms,
        values: Tensor<1>,
    ) {
        self.steps.push(PendingStep {
            step,
            phase,
            lr,
            names: terms.terms.iter().map(|(n, _)| *n).collect(),
            derived: std::mem::take(&mut terms.derived),
            metrics: std::mem::take(&mut terms.metrics),
            probes: std::mem::take(&mut terms.probes),
            on_device: Some(values),
            read: None,
            ms: 0.0,
            extra: Vec::new(),
        });
    }

    /// Records the newest step's time and its `after_step` numbers.
    pub fn finish_last(&mut self, ms: f64, extra: Vec<(String, f64)>) {
        if let Some(s) = self.steps.last_mut() {
            s.ms = ms;
            s.extra = extra;
        }
    }

    /// Reads every step not yet read, in one transfer.
    fn fetch(&mut self) -> Result<(), TrainError> {
        let unread: Vec<usize> = (0..self.steps.len())
            .filter(|&i| self.steps[i].on_device.is_some())
            .collect();
        if unread.is_empty() {
            return Ok(());
        }
        let tensors = unread
            .iter()
            .filter_map(|&i| self.steps[i].on_device.take())
            .collect();
        for (i, values) in unread.into_iter().zip(read_back(tensors)?) {
            self.steps[i].read = Some(values);
        }
        Ok(())
    }

    /// Step `s`'s values, checked (see [`StepValues::check`]).
    fn check<O>(
        s: &PendingStep,
        phases: &[Phase<O>],
        last_checkpoint: &impl Fn() -> Option<std::path::PathBuf>,
    ) -> Result<StepValues, TrainError> {
        let values = s.read.as_deref().expect("fetched");
        StepValues::check(
            values,
            &s.names,
            &phases[s.phase],
            s.step,
            s.lr,
            last_checkpoint,
        )
    }

    /// Reads every step waiting (in one transfer) and checks them in order: the first that
    /// diverged is the error. They stay in the queue.
    pub fn read<O>(
        &mut self,
        phases: &[Phase<O>],
        last_checkpoint: impl Fn() -> Option<std::path::PathBuf>,
    ) -> Result<(), TrainError> {
        self.fetch()?;
        for s in &self.steps {
            Self::check(s, phases, &last_checkpoint)?;
        }
        Ok(())
    }

    /// Reads what is unread, then empties the queue in order: each step's probes observed by
    /// `watch`, its values set in `last`, its record and warnings returned, up to the first
    /// step that diverged, whose error comes with them.
    pub fn drain<O>(
        &mut self,
        phases: &[Phase<O>],
        last_checkpoint: impl Fn() -> Option<std::path::PathBuf>,
        watch: &mut ProbeWatch,
        last: &mut BTreeMap<String, f64>,
    ) -> Drained {
        if let Err(e) = self.fetch() {
            self.steps.clear();
            return Drained {
                logged: Vec::new(),
                error: Some(e),
            };
        }
        let mut logged = Vec::with_capacity(self.steps.len());
        for s in self.steps.drain(..) {
            let values = match Self::check(&s, phases, &last_checkpoint) {
                Ok(v) => v,
                Err(e) => {
                    return Drained {
                        logged,
                        error: Some(e),
                    };
                }
            };
            let warnings = watch.observe(&s.probes, &values.probes, s.step);
            let mut record = serde_json::Map::new();
            record.insert("step".into(), s.step.into());
            record.insert("phase".into(), phases[s.phase].name.clone().into());
            for (name, v) in &values.terms {
                last.insert(name.to_string(), *v);
                record.insert(name.to_string(), (*v).into());
            }
            for (name, term, f) in &s.derived {
                if let Some((_, v)) = values.terms.iter().find(|(n, _)| n == term) {
                    let d = f(*v);
                    last.insert(name.to_string(), d);
                    record.insert(name.to_string(), d.into());
                }
            }
            for (name, v) in s.metrics.iter().chain(&s.extra) {
                last.insert(name.clone(), *v);
                record.insert(name.clone(), (*v).into());
            }
            for (probe, &v) in s.probes.iter().zip(&values.probes) {
                last.insert(probe.name.to_string(), v);
                record.insert(probe.name.to_string(), v.into());
            }
            record.insert("loss".into(), values.total_value.into());
            record.insert("lr".into(), s.lr.into());
            record.insert("ms".into(), s.ms.into());
            logged.push(Logged {
                step: s.step,
                record,
                has_extra: !s.extra.is_empty(),
                warnings,
            });
        }
        Drained {
            logged,
            error: None,
        }
    }
}
