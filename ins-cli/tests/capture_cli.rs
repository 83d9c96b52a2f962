//! Users' own captures through the CLI: `data synth --format colmap|transforms` writes them,
//! `data check` passes them, `train nerf` learns a capture whose ground plane runs past the
//! cameras, and `data sfm` refuses what it cannot pose with one clear message.

mod common;
use common::*;

/// Held-out PSNR a 300-step tiny grid NeRF reaches on the 32-px synthetic tabletop capture
/// (objects on an endless checkered ground, 12 views through a distorting lens). Measured
/// 21.9–22.4 dB over seeds 0–2 on this project's 2-core machine; a capture read in the wrong
/// frame, or rays that miss the background's box, stays near 12 dB (the mean colour).
const CAPTURE_PSNR_BAR: f64 = 18.0;

#[test]
fn a_capture_with_background_checks_and_trains() {
    let dir = tempfile::tempdir().unwrap();
    for (format, extra) in [("colmap", vec!["--text"]), ("transforms", vec![])] {
        let scene = dir.path().join(format);
        let mut args = vec![
            "data",
            "synth",
            "--format",
            format,
            "--out",
            s(&scene),
            "--size",
            "32",
            "--views",
            "12",
        ];
        args.extend(extra);
        ok(cli(&args));
        let o = ok(cli(&["data", "check", s(&scene), "--no-sheet"]));
        let text = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(text.contains(&format!("({format})")), "{text}");
        assert!(text.contains("object-centred: box"), "{text}");
        assert!(text.contains("lens     Polynomial"), "{text}");
    }
    let run = dir.path().join("run");
    let scene = dir.path().join("colmap");
    let mut args = vec!["train", "nerf", "--scene", s(&scene), "--out", s(&run)];
    args.extend_from_slice(NERF_TINY);
    let steps = args.iter().position(|a| *a == "--steps").unwrap() + 1;
    args[steps] = "300";
    let eval_every = args.iter().position(|a| *a == "--eval-every").unwrap() + 1;
    args[eval_every] = "300";
    ok(cli(&args));
    let o = ok(cli(&[
        "eval",
        "nerf",
        "--run",
        s(&run),
        "--backend",
        "flex",
    ]));
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    let mean: serde_json::Value =
        serde_json::from_str(text.lines().last().expect("a mean line")).unwrap();
    let psnr = mean["psnr"].as_f64().expect("psnr in the mean line");
    assert!(psnr > CAPTURE_PSNR_BAR, "held-out PSNR {psnr} dB: {text}");
}

#[test]
fn sfm_refuses_what_it_cannot_pose() {
    let dir = tempfile::tempdir().unwrap();
    let o = cli(&[
        "data",
        "sfm",
        "--images",
        s(&dir.path().join("absent")),
        "--out",
        s(&dir.path().join("ws")),
    ]);
    assert_clean_failure(&o, "absent");
    let photos = dir.path().join("two");
    std::fs::create_dir_all(&photos).unwrap();
    for i in 0..2 {
        image::RgbImage::new(8, 8)
            .save(photos.join(format!("{i}.png")))
            .unwrap();
    }
    let o = cli(&[
        "data",
        "sfm",
        "--images",
        s(&photos),
        "--out",
        s(&dir.path().join("ws")),
    ]);
    assert_clean_failure(&o, "at least 3");
    // A folder without a model is not a scene, and the message says how to make one.
    let o = cli(&["data", "check", s(&photos), "--no-sheet"]);
    assert_clean_failure(&o, "data sfm");
}
