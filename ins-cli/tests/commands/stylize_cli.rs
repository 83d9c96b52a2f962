//! `ins-cli stylize`, the one command from photos and a painting to a video, a report and a
//! mesh: every stage on a small synthetic capture, a re-run that keeps what is finished, a new
//! painting that redoes only the stylization and what follows it, a stopped stage that
//! continues, and bad input refused before any long stage.
//!
//! Structure from motion is COLMAP through pycolmap, installed on first use (100 MB from PyPI):
//! here a stand-in takes its place in the cache's environment, a script that copies the
//! workspace `data synth --format colmap` wrote for the same photos and prints the summary the
//! real script prints. What is tested is the stage logic around it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::*;

/// Runs `ins-cli args…` with `INS_CACHE_DIR=cache` (the stand-in SfM's environment) and the
/// workspace it copies.
fn cli_with(args: &[&str], cache: &Path, workspace: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ins-cli"))
        .args(args)
        .env("INS_NO_GPU", "1")
        .env("RUST_BACKTRACE", "0")
        .env("INS_CACHE_DIR", cache)
        .env("FAKE_SFM_WORKSPACE", workspace)
        .output()
        .expect("running ins-cli")
}

/// A cache folder whose pycolmap environment is the stand-in, sharing the real cache's VGG-16
/// (fetched first if needed).
fn stand_in_cache(dir: &Path) -> PathBuf {
    ok(cli(&["vgg", "fetch"]));
    let cache = dir.join("cache");
    let venv = cache.join("pycolmap-venv");
    std::fs::create_dir_all(venv.join("bin")).unwrap();
    std::os::unix::fs::symlink(
        vgg_import::source::cache_dir(None).join("vgg16"),
        cache.join("vgg16"),
    )
    .unwrap();
    let python = venv.join("bin/python");
    std::fs::write(
        &python,
        r#"#!/bin/sh
# Stands in for `python sfm.py --images DIR --out WS …`: the prepared workspace, posed.
while [ $# -gt 0 ]; do [ "$1" = --out ] && out=$2; shift; done
mkdir -p "$out" && cp -r "$FAKE_SFM_WORKSPACE"/sparse "$FAKE_SFM_WORKSPACE"/images "$out"/
n=$(ls "$out"/images | wc -l)
echo "sfm: $n photos (stand-in)"
echo "SUMMARY {\"photos\": $n, \"registered\": $n, \"points\": 0, \"reprojection_error_px\": 0.5, \"unregistered\": [], \"cameras\": []}"
"#,
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&python, std::fs::Permissions::from_mode(0o755)).unwrap();
    std::fs::write(venv.join(".ins-ready"), "stand-in").unwrap();
    cache
}

/// The stages `stylize.json` records as finished, with their input fingerprints.
fn stages(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("stylize.json")).unwrap()).unwrap()
}

/// When a run's newest checkpoint was written.
fn checkpoint_time(run: &Path) -> std::time::SystemTime {
    let latest = std::fs::read_to_string(run.join("checkpoints/latest")).unwrap();
    std::fs::metadata(run.join("checkpoints").join(latest.trim()))
        .unwrap()
        .modified()
        .unwrap()
}

#[test]
fn photos_to_video_report_and_mesh_in_one_command_that_continues_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let workspace = dir.path().join("workspace");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "colmap",
        "--layout",
        "object",
        "--size",
        "32",
        "--views",
        "12",
        "--out",
        s(&workspace),
    ]));
    let photos = workspace.join("images");
    let cache = stand_in_cache(dir.path());
    let painting = gradient_painting(&dir.path().join("painting.png"));
    let out = dir.path().join("mine");
    let args = |style: &Path| -> Vec<String> {
        [
            "stylize",
            "--photos",
            s(&photos),
            "--style",
            s(style),
            "--out",
            s(&out),
            "--pretrain-steps",
            "12",
            "--stylize-steps",
            "3",
            "--frames",
            "8",
            "--mesh-resolution",
            "48",
            "--downscale",
            "1",
            "--quiet",
            "--backend",
            "flex",
        ]
        .map(String::from)
        .to_vec()
    };
    let run = |style: &Path| {
        let a = args(style);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        ok(cli_with(&a, &cache, &workspace))
    };

    // Every stage, in order, into one folder.
    let o = run(&painting);
    let err = stderr(&o);
    for line in [
        "stages: 1 poses (structure from motion) · 2 pretrain (NeRF) · 3 stylize · 4 video, report, mesh",
        "[1/4] poses: starting",
        "[2/4] pretrain: starting",
        "[3/4] stylize: starting",
        "[4/4] outputs: starting",
    ] {
        assert!(err.contains(line), "no {line:?} in: {err}");
    }
    // Each training prints its summary line; the command's own comes last.
    let stdout = String::from_utf8_lossy(&o.stdout);
    let summary: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    let video = PathBuf::from(summary["video"].as_str().unwrap());
    assert!(video.starts_with(out.join("renders")), "{summary}");
    assert!(
        matches!(
            video.extension().and_then(|e| e.to_str()),
            Some("mp4" | "gif")
        ),
        "{summary}"
    );
    assert!(std::fs::metadata(&video).unwrap().len() > 0);
    let page = std::fs::read_to_string(out.join("report/index.html")).unwrap();
    assert!(page.contains("<h1>"), "not a report page");
    // The pretraining's held-out score, evaluated once at its last step.
    assert!(
        page.contains("val_psnr"),
        "the report shows no held-out PSNR of the pretraining"
    );
    // A mesh where the field has a surface; a few steps may leave fog, which the report and
    // the log name.
    match summary["mesh"].as_str() {
        Some(mesh) => assert!(Path::new(mesh).is_file(), "{summary}"),
        None => assert!(
            page.contains("No mesh:") && err.contains("the report shows no mesh"),
            "{summary}\n{err}"
        ),
    }
    for stage in ["poses", "pretrain", "stylize", "outputs"] {
        assert_eq!(stages(&out)["stages"][stage]["finished"], true, "{stage}");
    }
    let pretrained_at = checkpoint_time(&out.join("pretrained"));
    let stylized_at = checkpoint_time(&out.join("stylized"));

    // The same command again: every stage kept, nothing trained again.
    let err = stderr(&run(&painting));
    for stage in [
        "[1/4] poses",
        "[2/4] pretrain",
        "[3/4] stylize",
        "[4/4] outputs",
    ] {
        assert!(
            err.contains(&format!("{stage}: kept")),
            "{stage} not kept: {err}"
        );
    }
    assert_eq!(checkpoint_time(&out.join("stylized")), stylized_at);

    // A stylization stopped before its end continues from its checkpoint.
    let mut manifest = stages(&out);
    manifest["stages"]["stylize"]["finished"] = false.into();
    std::fs::write(out.join("stylize.json"), manifest.to_string()).unwrap();
    let err = stderr(&run(&painting));
    assert!(
        err.contains("[3/4] stylize: resuming where it stopped"),
        "{err}"
    );
    assert!(err.contains("[4/4] outputs: kept"), "{err}");

    // Another painting: the poses and the pretraining are kept, the rest is done again.
    let other = dir.path().join("other.png");
    image::RgbImage::from_fn(32, 32, |x, y| {
        image::Rgb(if (x / 8 + y / 8) % 2 == 0 {
            [230, 40, 20]
        } else {
            [20, 30, 200]
        })
    })
    .save(&other)
    .unwrap();
    let err = stderr(&run(&other));
    assert!(err.contains("[1/4] poses: kept"), "{err}");
    assert!(err.contains("[2/4] pretrain: kept"), "{err}");
    assert!(err.contains("[3/4] stylize: starting"), "{err}");
    assert!(err.contains("[4/4] outputs: starting"), "{err}");
    assert_eq!(checkpoint_time(&out.join("pretrained")), pretrained_at);
    let config = std::fs::read_to_string(out.join("stylized/config.json")).unwrap();
    assert!(config.contains("other.png"), "{config}");
}

#[test]
fn bad_input_stops_before_any_stage_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let photos = dir.path().join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    for i in 0..3 {
        image::RgbImage::new(16, 16)
            .save(photos.join(format!("{i}.png")))
            .unwrap();
    }
    let painting = gradient_painting(&dir.path().join("painting.png"));
    let out = dir.path().join("out");
    let o = cli(&[
        "stylize",
        "--photos",
        s(&photos),
        "--style",
        s(&painting),
        "--out",
        s(&out),
    ]);
    assert_clean_failure(&o, "at least 8");
    let text = dir.path().join("notes.png");
    std::fs::write(&text, "not a picture").unwrap();
    let o = cli(&[
        "stylize",
        "--photos",
        s(&photos),
        "--style",
        s(&text),
        "--out",
        s(&out),
    ]);
    assert_clean_failure(&o, "notes.png");
    let o = cli(&[
        "stylize",
        "--photos",
        s(&dir.path().join("absent")),
        "--style",
        s(&painting),
        "--out",
        s(&out),
    ]);
    assert_clean_failure(&o, "absent");
    assert!(!out.exists(), "a refused run wrote {}", out.display());
}
