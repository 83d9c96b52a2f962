//! Kill-safe runs: a real `ins-cli train siren` process is killed with SIGKILL at random
//! moments (one of them while a checkpoint is being written), resumed with `--resume` each
//! time, and ends with the same parameters as a run that was never interrupted.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use ins_models::siren::SirenRun;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

fn train_args(out: &Path) -> Vec<String> {
    [
        "train",
        "siren",
        "--out",
        out.to_str().unwrap(),
        "--size",
        "24",
        "--style-size",
        "32",
        "--fit-steps",
        "40",
        "--stylize-steps",
        "20",
        "--hidden",
        "64",
        "--depth",
        "3",
        "--patch",
        "24",
        "--stride",
        "1",
        "--fit-batch",
        "576",
        "--lr-stylize",
        "2e-4",
        "--checkpoint-every",
        "4",
        "--quiet",
        "--backend",
        "flex",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

fn spawn(out: &Path, resume: bool, checkpoint_delay_ms: Option<u64>) -> Child {
    let mut c = Command::new(env!("CARGO_BIN_EXE_ins-cli"));
    c.args(train_args(out))
        .env("INS_NO_GPU", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    if resume {
        c.arg("--resume");
    }
    if let Some(ms) = checkpoint_delay_ms {
        c.env("INS_FAULT_CHECKPOINT_DELAY_MS", ms.to_string());
    }
    c.spawn().expect("starting ins-cli")
}

fn finish(child: Child) {
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "run failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every float parameter, in visiting order.
fn parameters<M: Module>(m: &M) -> Vec<f32> {
    struct All(Vec<f32>);
    impl ModuleVisitor for All {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            self.0.extend(
                p.val()
                    .into_data()
                    .convert::<f32>()
                    .try_to_vec::<f32>()
                    .unwrap(),
            );
        }
    }
    let mut v = All(Vec::new());
    m.visit(&mut v);
    v.0
}

/// `latest`, when present, names a folder that holds every file of a checkpoint.
fn assert_latest_complete(run: &Path) {
    let ck = run.join("checkpoints");
    let Ok(name) = std::fs::read_to_string(ck.join("latest")) else {
        return;
    };
    let dir = ck.join(name.trim());
    for f in ["model.bpk", "optim.bpk", "state.json"] {
        assert!(
            dir.join(f).is_file(),
            "latest names {} without {f}",
            dir.display()
        );
    }
}

fn has_checkpoint(run: &Path) -> bool {
    run.join("checkpoints/latest").exists()
}

/// Waits until a checkpoint is being written (its temporary folder exists).
fn wait_for_checkpoint_write(run: &Path, limit: Duration) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if let Ok(entries) = std::fs::read_dir(run.join("checkpoints"))
            && entries
                .filter_map(|e| e.ok())
                .any(|e| e.file_name().to_string_lossy().starts_with(".step-"))
        {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

/// The last step recorded in the run's metrics, if any.
fn last_logged_step(run: &Path) -> Option<u64> {
    let log = std::fs::read_to_string(run.join("metrics.jsonl")).ok()?;
    log.lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["step"].as_u64())
        .next_back()
}

/// Waits until the run has logged `step` (true) or the process ended or time ran out (false).
fn wait_for_step(run: &Path, child: &mut Child, step: u64, limit: Duration) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        if last_logged_step(run).is_some_and(|s| s >= step) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    false
}

#[test]
fn killed_runs_resume_to_the_same_parameters_as_an_uninterrupted_one() {
    let dir = tempfile::tempdir().unwrap();
    let a: PathBuf = dir.path().join("uninterrupted");
    finish(spawn(&a, false, None));

    let b: PathBuf = dir.path().join("killed");
    // The demo inputs the first run generated; the killed run must train on the same ones.
    std::fs::create_dir_all(b.join("inputs")).unwrap();
    for f in ["demo_content.png", "bridgewater_madonna.png"] {
        std::fs::copy(a.join("inputs").join(f), b.join("inputs").join(f)).unwrap();
    }
    let mut rng = SmallRng::seed_from_u64(11);
    let mut kills = 0;
    // First kill: in the middle of a checkpoint write.
    let child = spawn(&b, false, Some(3000));
    let mut child = child;
    assert!(
        wait_for_checkpoint_write(&b, Duration::from_secs(120)),
        "no checkpoint write started"
    );
    child.kill().unwrap();
    child.wait().unwrap();
    kills += 1;
    assert_latest_complete(&b);
    // Then at random moments: after a random number of newly logged steps plus a random
    // fraction of a step, resuming each time (or starting again when nothing was saved).
    // Counting steps rather than seconds keeps every kill inside the run on a fast machine.
    for _ in 0..4 {
        let target = last_logged_step(&b).map_or(0, |s| s + 1) + rng.random_range(1..=6);
        let mut child = spawn(&b, has_checkpoint(&b), None);
        let landed = wait_for_step(&b, &mut child, target, Duration::from_secs(120));
        std::thread::sleep(Duration::from_millis(rng.random_range(0..40)));
        if landed && child.try_wait().unwrap().is_none() {
            child.kill().unwrap();
            kills += 1;
        }
        child.wait().unwrap();
        assert_latest_complete(&b);
    }
    assert!(kills >= 3, "only {kills} kills landed");
    finish(spawn(&b, has_checkpoint(&b), None));

    let device = Device::flex();
    let pa = parameters(&SirenRun::load(&a, &device).unwrap().model);
    let pb = parameters(&SirenRun::load(&b, &device).unwrap().model);
    assert_eq!(pa.len(), pb.len());
    let diff = pa
        .iter()
        .zip(&pb)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(
        diff <= 1e-5,
        "resumed run ends {diff} away from the uninterrupted one"
    );
    // The resumed run's metrics cover every step once, in order.
    let log = std::fs::read_to_string(b.join("metrics.jsonl")).unwrap();
    let steps: Vec<u64> = log
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["step"]
                .as_u64()
                .unwrap()
        })
        .collect();
    let mut sorted = steps.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(steps, sorted);
    assert_eq!(steps.last(), Some(&59));
}
