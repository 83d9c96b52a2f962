//! The shared trainer on a toy model: NaN guard with the last good checkpoint kept, frozen
//! groups, per-group learning rates, phases.

use anyhow::Result;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::Gradients;
use ins_core::train::checkpoint::{CheckpointStore, load_module_bytes};
use ins_core::train::groups::{OptimGroups, Optimizable};
use ins_core::train::{LossTerms, Phase, Task, TrainOptions, Trainer};
use ins_tests::values;

#[derive(Module, Debug)]
struct Toy {
    a: Linear,
    b: Linear,
}

impl Optimizable for Toy {
    fn group_names() -> &'static [&'static str] {
        &["a", "b"]
    }
    fn optimize(self, grads: &mut Gradients, lr: f64, groups: &mut OptimGroups) -> Self {
        Self {
            a: groups.step("a", self.a, grads, lr),
            b: groups.step("b", self.b, grads, lr),
        }
    }
}

fn toy(device: &Device) -> Toy {
    device.seed(0);
    Toy {
        a: LinearConfig::new(2, 2).init(device),
        b: LinearConfig::new(2, 1).init(device),
    }
}

/// Regression of y = x0 − x1; turns the loss into NaN from `nan_from` on.
struct ToyTask {
    nan_from: usize,
    global: usize,
}

impl Task for ToyTask {
    type Model = Toy;
    fn losses(
        &mut self,
        model: &Toy,
        _phase: &Phase,
        _step: usize,
        _seed: u64,
    ) -> Result<LossTerms> {
        let device = model.a.weight.val().device();
        let x =
            Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [2.0, -1.0]], &device);
        let y = Tensor::<2>::from_floats([[1.0], [-1.0], [0.0], [3.0]], &device);
        let mut loss = (model.b.forward(model.a.forward(x)) - y).square().mean();
        if self.global >= self.nan_from {
            loss = loss.mul_scalar(f32::NAN);
        }
        self.global += 1;
        Ok(LossTerms::default().term("mse", loss))
    }
}

fn quiet(dir: &std::path::Path) -> TrainOptions {
    let mut o = TrainOptions::new(dir);
    o.quiet = true;
    o.checkpoint_every = 2;
    o.log_every = 1;
    o
}

#[test]
fn training_lowers_the_loss() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![Phase::new("fit", 600, 2e-2)], quiet(dir.path()));
    let out = t
        .run(
            &mut ToyTask {
                nan_from: usize::MAX,
                global: 0,
            },
            toy(&device),
        )
        .unwrap();
    assert!(out.last["mse"] < 1e-3, "final loss {}", out.last["mse"]);
}

#[test]
fn nan_stops_with_a_clear_message_and_keeps_the_last_good_checkpoint() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let t = Trainer::new(vec![Phase::new("fit", 20, 1e-2)], quiet(dir.path()));
    let err = t
        .run(
            &mut ToyTask {
                nan_from: 5,
                global: 0,
            },
            toy(&device),
        )
        .err()
        .expect("NaN must stop the run");
    let msg = format!("{err:#}");
    assert!(msg.contains("diverged") && msg.contains("step 5"), "{msg}");
    assert!(
        msg.contains("step-00000004"),
        "message should name the last good checkpoint: {msg}"
    );
    // The checkpoint it names is complete and loads.
    let store = CheckpointStore::new(dir.path().join("checkpoints"), 2);
    let ckpt = store.load_latest().unwrap().unwrap();
    assert_eq!(ckpt.step, 4);
    let m = load_module_bytes(toy(&device), ckpt.model, store.dir()).unwrap();
    assert!(values(m.a.weight.val()).iter().all(|v| v.is_finite()));
}

#[test]
fn frozen_group_keeps_its_parameters_and_lr_multiplier_scales_steps() {
    let device = Device::flex().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let start = toy(&device);
    let a0 = values(start.a.weight.val());
    let b0 = values(start.b.weight.val());
    let t = Trainer::new(
        vec![Phase::new("fit", 5, 1e-2).freeze("a")],
        quiet(dir.path()),
    );
    let out = t
        .run(
            &mut ToyTask {
                nan_from: usize::MAX,
                global: 0,
            },
            start,
        )
        .unwrap();
    assert_eq!(values(out.model.a.weight.val()), a0, "frozen group moved");
    assert_ne!(
        values(out.model.b.weight.val()),
        b0,
        "trained group did not move"
    );

    // Adam moves each parameter by about lr per step at first: with a multiplier of 0.1 the
    // first step moves `a` ten times less than `b`'s scale.
    let dir2 = tempfile::tempdir().unwrap();
    let start = toy(&device);
    let a0 = values(start.a.weight.val());
    let t = Trainer::new(
        vec![Phase::new("fit", 1, 1e-2).lr_mult("a", 0.1)],
        quiet(dir2.path()),
    );
    let out = t
        .run(
            &mut ToyTask {
                nan_from: usize::MAX,
                global: 0,
            },
            start,
        )
        .unwrap();
    let moved = values(out.model.a.weight.val())
        .iter()
        .zip(&a0)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(
        (moved - 1e-3).abs() < 2e-4,
        "first Adam step with lr 1e-2 × 0.1 moved {moved}"
    );
}
