//! The shared trainer on a toy model: NaN guard with the last good checkpoint kept, frozen
//! groups, per-group learning rates, phases, configurations refused before a step runs, and a
//! watched probe's warning at the same step whether or not the run was resumed.

use anyhow::Result;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes};
use ins_core::train::{
    GroupSpec, LossTerms, Optimizable, Phase, Probe, StepContext, Task, TrainError, TrainOptions,
    Trainer, Watch,
};
use ins_tests::values;

#[derive(Module, Debug)]
struct Toy {
    a: Linear,
    b: Linear,
}

impl Optimizable for Toy {
    fn groups(&self) -> Vec<GroupSpec> {
        vec![GroupSpec::new("a", &["a"]), GroupSpec::new("b", &["b"])]
    }
}

/// The toy model, seeded; drawn under the seeding lock, since this module's tests run in
/// parallel on one device and its generator is shared (a parallel draw once gave a second run
/// another model, the fresh-clone CI of the forty-eighth session).
fn toy(device: &Device) -> Toy {
    ins_core::train::seeding::seeded(device, 0, || Toy {
        a: LinearConfig::new(2, 2).init(device),
        b: LinearConfig::new(2, 1).init(device),
    })
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Fit {
    Regress,
}

/// Regression of y = x0 − x1; turns the loss into NaN from `nan_from` on, and into a constant
/// no parameter reaches at the steps listed in `untracked`; with `watched`, reports a probe
/// always past its limit (a warning after [`WATCHED_STEPS`] steps).
struct ToyTask {
    nan_from: usize,
    global: usize,
    untracked: Vec<usize>,
    watched: bool,
}

const WATCHED_STEPS: usize = 5;

impl Task for ToyTask {
    type Model = Toy;
    type Objective = Fit;
    fn terms(&self, _: Fit) -> &'static [&'static str] {
        &["mse"]
    }
    fn losses(&mut self, model: &Toy, _step: &StepContext<Fit>) -> Result<LossTerms> {
        let device = model.a.weight.val().device();
        let x =
            Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [2.0, -1.0]], &device);
        let y = Tensor::<2>::from_floats([[1.0], [-1.0], [0.0], [3.0]], &device);
        let mut loss = (model.b.forward(model.a.forward(x)) - y).square().mean();
        if self.global >= self.nan_from {
            loss = loss.mul_scalar(f32::NAN);
        }
        if self.untracked.contains(&self.global) {
            loss = Tensor::<1>::from_floats([0.5], &device);
        }
        self.global += 1;
        let terms = LossTerms::default().term("mse", loss);
        Ok(if self.watched {
            terms.probe(Probe {
                name: "stuck",
                value: Tensor::from_floats([1.0], &device),
                watch: Some(Watch {
                    limit: 0.5,
                    steps: WATCHED_STEPS,
                    warning: "the toy is stuck".into(),
                }),
            })
        } else {
            terms
        })
    }
}

fn task() -> ToyTask {
    ToyTask {
        nan_from: usize::MAX,
        global: 0,
        untracked: Vec::new(),
        watched: false,
    }
}

fn quiet(dir: &std::path::Path) -> TrainOptions {
    let mut o = TrainOptions::new(dir);
    o.quiet = true;
    o.checkpoint_every = 2;
    o.log_every = 1;
    o
}

fn fit(steps: usize, lr: f64) -> Phase<Fit> {
    Phase::new("fit", Fit::Regress, steps, lr)
}

#[test]
fn training_lowers_the_loss() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![fit(600, 2e-2)], quiet(dir.path()));
    let out = t.run(&mut task(), toy(&device)).unwrap();
    assert!(out.last["mse"] < 1e-3, "final loss {}", out.last["mse"]);
    assert!(dir.path().join("loss_curve.png").exists());
}

#[test]
fn nan_stops_with_a_typed_error_and_keeps_the_last_good_checkpoint() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![fit(20, 1e-2)], quiet(dir.path()));
    let mut nan = ToyTask {
        nan_from: 5,
        global: 0,
        untracked: Vec::new(),
        watched: false,
    };
    let err = t
        .run(&mut nan, toy(&device))
        .err()
        .expect("NaN must stop the run");
    let TrainError::Diverged {
        term,
        step,
        checkpoint,
        ..
    } = &err
    else {
        panic!("expected Diverged, got {err}");
    };
    assert_eq!((term.as_str(), *step), ("mse", 5));
    let checkpoint = checkpoint
        .clone()
        .expect("a checkpoint was written at step 4");
    assert!(
        checkpoint.ends_with("step-00000004-000"),
        "{}",
        checkpoint.display()
    );
    let msg = err.to_string();
    assert!(
        msg.contains("diverged") && msg.contains("step-00000004-000"),
        "{msg}"
    );
    // The checkpoint it names is complete and loads.
    let ckpt = CheckpointStore::load_dir(&checkpoint).unwrap();
    assert_eq!(ckpt.step, 4);
    let m = load_module_bytes(toy(&device), ckpt.model, &checkpoint).unwrap();
    assert!(values(m.a.weight.val()).iter().all(|v| v.is_finite()));
}

#[test]
fn frozen_group_keeps_its_parameters_and_lr_multiplier_scales_steps() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let start = toy(&device);
    let a0 = values(start.a.weight.val());
    let b0 = values(start.b.weight.val());
    let t = Trainer::new(vec![fit(5, 1e-2).freeze("a")], quiet(dir.path()));
    let out = t.run(&mut task(), start).unwrap();
    assert_eq!(values(out.model.a.weight.val()), a0, "frozen group moved");
    assert_ne!(
        values(out.model.b.weight.val()),
        b0,
        "trained group did not move"
    );

    // Adam moves each parameter by about lr on its first step: with a multiplier of 0.1 the
    // first step moves `a` by 1e-3.
    let dir2 = tempfile::tempdir().unwrap();
    let start = toy(&device);
    let a0 = values(start.a.weight.val());
    let b0 = values(start.b.weight.val());
    let t = Trainer::new(vec![fit(1, 1e-2).lr_mult("a", 0.1)], quiet(dir2.path()));
    let out = t.run(&mut task(), start).unwrap();
    let moved = |now: Vec<f32>, before: &[f32]| {
        now.iter()
            .zip(before)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let ma = moved(values(out.model.a.weight.val()), &a0);
    let mb = moved(values(out.model.b.weight.val()), &b0);
    assert!(
        (ma - 1e-3).abs() < 2e-4,
        "first Adam step with lr 1e-2 × 0.1 moved {ma}"
    );
    assert!(
        (mb - 1e-2).abs() < 2e-3,
        "first Adam step with lr 1e-2 moved {mb}"
    );
}

#[test]
fn misconfigured_phases_are_refused_before_any_step() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let run = |phase: Phase<Fit>| {
        Trainer::new(vec![phase], quiet(dir.path()))
            .run(&mut task(), toy(&device))
            .err()
            .expect("must be refused")
    };
    let e = run(fit(3, 1e-2).freeze("c"));
    assert!(
        matches!(&e, TrainError::UnknownGroup { group, .. } if group == "c"),
        "{e}"
    );
    assert!(e.to_string().contains("groups: a, b"), "{e}");
    let e = run(fit(3, 1e-2).weight("msee", 1.0));
    assert!(
        matches!(&e, TrainError::UnknownTerm { term, .. } if term == "msee"),
        "{e}"
    );
    let e = run(fit(3, 1e-2).weight("mse", 0.0));
    assert!(matches!(&e, TrainError::NothingToMinimise { .. }), "{e}");
    // Nothing was written: the folder holds no run.
    assert!(!dir.path().join("checkpoints").exists());
}

#[test]
fn a_second_run_into_the_same_folder_is_refused_and_resume_needs_a_checkpoint() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![fit(3, 1e-2)], quiet(dir.path()));
    t.run(&mut task(), toy(&device)).unwrap();
    let e = t.run(&mut task(), toy(&device)).err().unwrap();
    assert!(matches!(e, TrainError::RunExists { .. }), "{e}");
    let empty = tempfile::tempdir().unwrap();
    let mut o = quiet(empty.path());
    o.resume = true;
    let e = Trainer::new(vec![fit(3, 1e-2)], o)
        .run(&mut task(), toy(&device))
        .err()
        .unwrap();
    assert!(matches!(e, TrainError::NothingToResume { .. }), "{e}");
}

#[test]
fn a_loss_no_parameter_reaches_skips_the_update() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![fit(4, 1e-2)], quiet(dir.path()));
    // Every step untracked: the run ends normally and nothing moved.
    let mut idle = ToyTask {
        untracked: (0..4).collect(),
        ..task()
    };
    let start = toy(&device);
    let before = values(start.a.weight.val());
    let out = t.run(&mut idle, start).unwrap();
    assert!(out.finished);
    assert_eq!(values(out.model.a.weight.val()), before);
    // One untracked step among tracked ones: the others still train.
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![fit(4, 1e-2)], quiet(dir.path()));
    let mut one = ToyTask {
        untracked: vec![1],
        ..task()
    };
    let out = t.run(&mut one, toy(&device)).unwrap();
    assert_ne!(values(out.model.a.weight.val()), before);
}

#[test]
fn a_watched_probe_warns_at_the_same_step_when_the_run_is_resumed() {
    let device = Device::flex().autodiff();
    let watched = || ToyTask {
        watched: true,
        ..task()
    };
    let dir = tempfile::tempdir().unwrap();
    let whole = Trainer::new(vec![fit(8, 1e-2)], quiet(dir.path()))
        .run(&mut watched(), toy(&device))
        .unwrap();
    let at = format!("step {}:", WATCHED_STEPS - 1);
    assert_eq!(whole.warnings.len(), 1, "{:?}", whole.warnings);
    assert!(whole.warnings[0].contains(&at), "{}", whole.warnings[0]);
    assert!(whole.warnings[0].contains("the toy is stuck"));

    // Stopped by a NaN at step 3, so the newest checkpoint is the one taken before step 2;
    // resumed from there: the run of steps past the limit counts the two steps before the
    // checkpoint, and step 2 once.
    let dir = tempfile::tempdir().unwrap();
    let mut o = quiet(dir.path());
    let mut failing = ToyTask {
        nan_from: 3,
        ..watched()
    };
    let e = Trainer::new(vec![fit(8, 1e-2)], o.clone())
        .run(&mut failing, toy(&device))
        .err()
        .unwrap();
    assert!(matches!(e, TrainError::Diverged { step: 3, .. }), "{e}");
    o.resume = true;
    let resumed = Trainer::new(vec![fit(8, 1e-2)], o)
        .run(&mut watched(), toy(&device))
        .unwrap();
    assert_eq!(resumed.warnings.len(), 1, "{:?}", resumed.warnings);
    assert!(resumed.warnings[0].contains(&at), "{}", resumed.warnings[0]);
}

/// Reading the loss values of several steps at once (as on a GPU) changes nothing the user sees:
/// the same metrics lines, the same checkpoints, and a NaN reported at the step that produced
/// it, with the last checkpoint taken before it.
#[test]
fn steps_read_back_together_log_and_stop_as_steps_read_one_by_one() {
    let device = Device::flex().autodiff();
    let lines = |dir: &std::path::Path| -> Vec<serde_json::Value> {
        std::fs::read_to_string(dir.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .map(|l| {
                let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
                v.as_object_mut().unwrap().remove("ms");
                v
            })
            .collect()
    };
    let run = |read_every: usize, nan_from: usize| {
        let dir = tempfile::tempdir().unwrap();
        let mut o = quiet(dir.path());
        o.read_every = Some(read_every);
        let out = Trainer::new(vec![fit(11, 1e-2)], o)
            .run(&mut ToyTask { nan_from, ..task() }, toy(&device));
        (dir, out)
    };
    let (one_dir, one) = run(1, usize::MAX);
    let (four_dir, four) = run(4, usize::MAX);
    let (one, four) = (one.unwrap(), four.unwrap());
    assert_eq!(lines(one_dir.path()).len(), 11);
    assert_eq!(lines(one_dir.path()), lines(four_dir.path()));
    assert_eq!(one.last, four.last);
    assert_eq!(
        values(one.model.b.weight.val()),
        values(four.model.b.weight.val())
    );

    // A NaN from step 5 on, read with steps 4..8 (the checkpoint at step 6 reads it first).
    let (dir, err) = run(4, 5);
    let err = err.err().expect("NaN must stop the run");
    let TrainError::Diverged {
        step, checkpoint, ..
    } = &err
    else {
        panic!("expected Diverged, got {err}");
    };
    assert_eq!(*step, 5);
    assert!(
        checkpoint.as_ref().unwrap().ends_with("step-00000004-000"),
        "{err}"
    );
    // Steps 0..5 were logged, as read one by one.
    assert_eq!(lines(dir.path()).len(), 5);
}
