//! Watching the probes a task reports: a run of steps past a probe's limit becomes one warning.

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use super::task::Probe;

/// How many steps in a row each watched probe has been past its limit, and which have warned.
///
/// Checkpoints keep the runs, so a run of steps that a resume cuts in two still counts whole.
/// They do not keep which probes warned: whoever resumes may not have seen the first process's
/// output, and a probe still past its limit warns again at once.
#[derive(Debug, Default, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct ProbeWatch {
    run: BTreeMap<String, usize>,
    #[serde(skip)]
    warned: BTreeSet<&'static str>,
}

impl ProbeWatch {
    /// Counts this step's `values` of `probes` (global step `step`); returns the warnings due,
    /// each once a run.
    pub fn observe(&mut self, probes: &[Probe], values: &[f64], step: usize) -> Vec<String> {
        let mut due = Vec::new();
        for (probe, &value) in probes.iter().zip(values) {
            let Some(watch) = &probe.watch else { continue };
            let run = self.run.entry(probe.name.to_string()).or_default();
            *run = if value > watch.limit { *run + 1 } else { 0 };
            if *run >= watch.steps.max(1) && self.warned.insert(probe.name) {
                due.push(format!(
                    "warning: step {step}: {} is {value:.2}, above {} for {} steps in a row: {}",
                    probe.name, watch.limit, *run, watch.warning
                ));
            }
        }
        due
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::task::Watch;
    use burn::prelude::*;

    fn probe(limit: f64) -> Probe {
        Probe {
            name: "saturated",
            value: Tensor::zeros([1], &Device::flex()),
            watch: Some(Watch {
                limit,
                steps: 3,
                warning: "lower --lr".into(),
            }),
        }
    }

    #[test]
    fn warns_once_after_enough_steps_in_a_row() {
        let mut w = ProbeWatch::default();
        let p = [probe(0.5)];
        // Two past, one under (the run restarts), then three past: the warning at the third.
        for (step, v) in [0.9, 0.9, 0.1, 0.6, 0.7].into_iter().enumerate() {
            assert!(w.observe(&p, &[v], step).is_empty(), "step {step}");
        }
        let due = w.observe(&p, &[0.8], 5);
        assert_eq!(due.len(), 1);
        assert!(
            due[0].contains("step 5") && due[0].contains("lower --lr"),
            "{}",
            due[0]
        );
        assert!(w.observe(&p, &[0.9], 6).is_empty(), "said twice");
    }

    #[test]
    fn a_saved_watch_keeps_the_run_and_warns_again_if_still_past() {
        let p = [probe(0.5)];
        let mut w = ProbeWatch::default();
        for step in 0..2 {
            assert!(w.observe(&p, &[0.9], step).is_empty());
        }
        let saved = serde_json::to_value(&w).unwrap();
        // Resumed after two steps past the limit: the third makes the warning.
        let mut resumed: ProbeWatch = serde_json::from_value(saved).unwrap();
        let due = resumed.observe(&p, &[0.9], 2);
        assert_eq!(due.len(), 1, "the run was not kept");
        assert!(due[0].contains("3 steps in a row"), "{}", due[0]);
        // Saved after it warned: a resumed process says it again once.
        let mut again: ProbeWatch =
            serde_json::from_value(serde_json::to_value(&resumed).unwrap()).unwrap();
        assert_eq!(again.observe(&p, &[0.9], 3).len(), 1);
        assert!(again.observe(&p, &[0.9], 4).is_empty());
        // An old checkpoint without a watch reads as a fresh one.
        let empty: ProbeWatch = serde_json::from_str("{}").unwrap();
        assert!(empty.run.is_empty());
    }

    #[test]
    fn a_probe_without_a_watch_never_warns() {
        let mut w = ProbeWatch::default();
        let mut p = probe(0.0);
        p.watch = None;
        for step in 0..10 {
            assert!(w.observe(std::slice::from_ref(&p), &[1.0], step).is_empty());
        }
    }
}
