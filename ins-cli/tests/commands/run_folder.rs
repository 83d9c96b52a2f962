//! Where a run can be hurt: two runs given the same `--out` at once, and a checkpoint that
//! cannot be written (a file-size limit, as a full disk would): the second run is refused with
//! the first one's pid, and a failed checkpoint leaves the last good one loadable, ending with
//! a clear error.

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::common::{assert_clean_failure, ok, s};

fn train_args(out: &Path) -> Vec<String> {
    [
        "train",
        "siren",
        "--out",
        s(out),
        "--size",
        "24",
        "--style-size",
        "32",
        "--fit-steps",
        "12",
        "--stylize-steps",
        "8",
        "--hidden",
        "128",
        "--depth",
        "3",
        "--patch",
        "24",
        "--stride",
        "1",
        "--fit-batch",
        "576",
        "--checkpoint-every",
        "4",
        "--quiet",
        "--backend",
        "flex",
    ]
    .iter()
    .map(|a| a.to_string())
    .collect()
}

fn command(out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_ins-cli"));
    c.args(train_args(out))
        .args(extra)
        .env("INS_NO_GPU", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    c
}

fn output(mut c: Command) -> Output {
    c.output().expect("running ins-cli")
}

/// Waits until `cond` holds, or fails the test after `limit`.
fn wait_until(what: &str, limit: Duration, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Whether a checkpoint is being written in the run folder `out` (its temporary folder exists).
fn writing_checkpoint(out: &Path) -> bool {
    std::fs::read_dir(out.join("checkpoints")).is_ok_and(|mut d| {
        d.any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().starts_with(".step-")))
    })
}

fn kill(mut child: Child) {
    child.kill().ok();
    child.wait().ok();
}

#[test]
fn a_second_run_into_a_folder_in_use_is_refused_with_the_first_ones_pid() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // The first run pauses for a minute inside its first checkpoint write.
    let mut first = command(&out, &[]);
    first.env("INS_FAULT_CHECKPOINT_DELAY_MS", "60000");
    let first = first.spawn().unwrap();
    let pid = first.id();
    wait_until(
        "the first checkpoint write",
        Duration::from_secs(120),
        || writing_checkpoint(&out),
    );
    let config = std::fs::read(out.join("config.json")).unwrap();
    for extra in [&[][..], &["--resume"][..]] {
        let second = output(command(&out, extra));
        assert_clean_failure(&second, &format!("in use by another run (pid {pid})"));
    }
    // The refused runs wrote nothing.
    assert_eq!(std::fs::read(out.join("config.json")).unwrap(), config);
    kill(first);
    // Once the first is gone (killed before its first checkpoint was published), the folder
    // takes a run again.
    ok(output(command(&out, &[])));
    assert!(out.join("preview.png").is_file());
}

#[test]
fn a_checkpoint_over_the_file_size_limit_keeps_the_last_good_one() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // A run stopped after its first checkpoint: every checkpoint write pauses for a second and
    // a half, and the run is killed during the second one.
    let mut first = command(&out, &[]);
    first.env("INS_FAULT_CHECKPOINT_DELAY_MS", "1500");
    let mut first = first.spawn().unwrap();
    let latest = out.join("checkpoints/latest");
    wait_until(
        "the second checkpoint write",
        Duration::from_secs(120),
        || latest.exists() && writing_checkpoint(&out),
    );
    first.kill().unwrap();
    first.wait().unwrap();
    let good = std::fs::read_to_string(&latest).unwrap();
    let model_size = std::fs::metadata(out.join("checkpoints").join(good.trim()).join("model.bpk"))
        .unwrap()
        .len();

    // Resumed under a file-size limit the model record no longer fits: the next checkpoint
    // fails, the run ends with a clear error naming the step, and the last good checkpoint is
    // the one `latest` still names.
    let leftovers = || -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(out.join("checkpoints"))
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().to_string())
            .filter(|n| n.starts_with(".step-"))
            .collect();
        v.sort();
        v
    };
    // The killed writer's half checkpoint, which the next complete save prunes.
    let killed_writer = leftovers();
    let mut limited = command(&out, &["--resume"]);
    let limit = model_size - 1;
    // SAFETY: setrlimit and signal are async-signal-safe and touch only the child.
    unsafe {
        limited.pre_exec(move || {
            // Ignored, SIGXFSZ turns an oversized write into EFBIG instead of killing.
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let lim = libc::rlimit {
                rlim_cur: limit,
                rlim_max: limit,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let failed = output(limited);
    assert_clean_failure(&failed, "writing the checkpoint of step");
    let e = crate::common::stderr(&failed);
    assert!(
        e.contains("File too large") && e.contains(good.trim()),
        "{e}"
    );
    assert_eq!(std::fs::read_to_string(&latest).unwrap(), good);
    // The failed write left no half checkpoint of its own behind.
    assert_eq!(leftovers(), killed_writer);
    // Without the limit the run continues from it to the end.
    ok(output(command(&out, &["--resume"])));
    let render = dir.path().join("r.png");
    ok(crate::common::cli(&[
        "render",
        "siren",
        "--run",
        s(&out),
        "--out",
        s(&render),
    ]));
    assert!(render.is_file());
}
