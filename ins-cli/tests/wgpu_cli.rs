//! The wgpu backend from the command line, where it fails: a machine without any adapter gets
//! one clear message saying what to do, at once, with nothing written.

mod common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{assert_clean_failure, s, stderr};

#[test]
fn wgpu_without_an_adapter_says_so_at_once_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // No Vulkan driver (an ICD list naming a missing file) and no EGL vendor for OpenGL: the
    // machine has no adapter at all, as a container without GPU drivers would.
    let mut child = Command::new(env!("CARGO_BIN_EXE_ins-cli"))
        .args(["train", "siren", "--backend", "wgpu", "--steps", "2", "--out"])
        .arg(s(&out))
        .env("VK_ICD_FILENAMES", dir.path().join("no_icd.json"))
        .env("__EGL_VENDOR_LIBRARY_FILENAMES", dir.path().join("no_egl.json"))
        .env("RUST_BACKTRACE", "0")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running ins-cli");
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > Duration::from_secs(120) {
            child.kill().ok();
            panic!("ins-cli --backend wgpu without an adapter did not end within 120 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = child.wait_with_output().unwrap();
    assert_clean_failure(&o, "no GPU adapter found");
    assert!(stderr(&o).contains("--backend flex"), "{}", stderr(&o));
    assert!(!out.exists(), "a failed start wrote {}", out.display());
}
