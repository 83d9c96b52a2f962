//! The wgpu backend from the command line (Mesa's lavapipe where there is no GPU): NeRF trains
//! on it as on flex, and a machine without any adapter gets one clear message saying
//! what to do, at once, with nothing written.

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{assert_clean_failure, ok, s, stderr};

/// Runs `ins-cli args…` with `env`, failing the test (not hanging the suite) after `limit`.
fn cli_within(args: &[&str], env: &[(&str, &Path)], limit: Duration) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_ins-cli"));
    c.args(args)
        .env("RUST_BACKTRACE", "0")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in env {
        c.env(k, v);
    }
    let mut child = c.spawn().expect("running ins-cli");
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > limit {
            child.kill().ok();
            panic!("ins-cli {args:?} did not end within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// The loss logged at step 9 of a run folder.
fn loss_at_step_9(run: &Path) -> f64 {
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    text.lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|v| v["step"] == 9)
        .and_then(|v| v["loss"].as_f64())
        .unwrap_or_else(|| panic!("no step 9 in {}", run.display()))
}

#[test]
fn nerf_trains_on_wgpu_as_on_flex() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    ok(common::cli(&[
        "data",
        "synth",
        "--format",
        "blender",
        "--out",
        s(&scene),
        "--size",
        "32",
        "--views",
        "8",
    ]));
    // The first wgpu run of a fresh machine compiles and tunes every kernel (about 4 minutes
    // on lavapipe here); IDR's first step takes longer still, so it is measured by hand
    // (docs/measurements.md) rather than in every CI run.
    let mut losses = Vec::new();
    for backend in ["flex", "wgpu"] {
        let run = dir.path().join(backend);
        let o = cli_within(
            &[
                "train",
                "nerf",
                "--scene",
                s(&scene),
                "--steps",
                "10",
                "--eval-every",
                "0",
                "--eval-views",
                "1",
                "--target-samples",
                "4096",
                "--log2-table",
                "12",
                "--max-resolution",
                "64",
                "--occupancy-resolution",
                "16",
                "--backend",
                backend,
                "--quiet",
                "--out",
                s(&run),
            ],
            &[],
            Duration::from_secs(1200),
        );
        assert!(o.status.success(), "NeRF on {backend}: {}", stderr(&o));
        losses.push(loss_at_step_9(&run));
    }
    // The same initial parameters (drawn on the CPU for every backend) and the same rays: only
    // the order of floating-point sums differs.
    let rel = (losses[1] - losses[0]).abs() / losses[0];
    assert!(
        rel < 1e-3,
        "loss at step 9: {} on wgpu, {} on flex",
        losses[1],
        losses[0]
    );
}

#[test]
fn wgpu_without_an_adapter_says_so_at_once_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // No Vulkan driver (an ICD list naming a missing file) and no EGL vendor for OpenGL: the
    // machine has no adapter at all, as a container without GPU drivers would.
    let (icd, egl) = (
        dir.path().join("no_icd.json"),
        dir.path().join("no_egl.json"),
    );
    let o = cli_within(
        &[
            "train",
            "siren",
            "--backend",
            "wgpu",
            "--steps",
            "2",
            "--out",
            s(&out),
        ],
        &[
            ("VK_ICD_FILENAMES", icd.as_path()),
            ("__EGL_VENDOR_LIBRARY_FILENAMES", egl.as_path()),
        ],
        Duration::from_secs(120),
    );
    assert_clean_failure(&o, "no GPU adapter found");
    assert!(stderr(&o).contains("--backend flex"), "{}", stderr(&o));
    assert!(!out.exists(), "a failed start wrote {}", out.display());
}
