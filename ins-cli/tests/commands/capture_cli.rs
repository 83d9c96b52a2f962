//! Users' own captures through the CLI: `data synth --format colmap|transforms` writes them,
//! `data check` passes them, `train nerf` learns a capture whose room runs past the cameras and
//! one before a plain backdrop, and `data sfm` refuses what it cannot pose with one clear
//! message.

use crate::common::*;

/// Held-out PSNR a 600-step small grid NeRF must reach on the synthetic room capture (objects
/// on a tiled floor inside a dome three times farther out than the cameras, 40 views of 64×48
/// through a distorting lens, the background contracted). Measured 21.62–21.70 dB over seeds
/// 0–2 on this project's 2-core machine (AMD EPYC, 2026-11-26); predicting the training views'
/// mean colour gives 16.5 dB, and a box holding the dome (`aabb_scale` 8) 21.4 dB.
const CAPTURE_PSNR_BAR: f64 = 20.0;

/// Trains the capture network (`NERF_SMALL`) on `scene` into `run` and returns the mean line
/// of `eval nerf` on its held-out views.
fn train_and_evaluate(scene: &std::path::Path, run: &std::path::Path) -> serde_json::Value {
    let mut args = vec!["train", "nerf", "--scene", s(scene), "--out", s(run)];
    args.extend_from_slice(NERF_SMALL);
    ok(cli(&args));
    let o = ok(cli(&["eval", "nerf", "--run", s(run), "--backend", "flex"]));
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    serde_json::from_str(text.lines().last().expect("a mean line")).unwrap()
}

/// Writes a synthetic capture (`data synth`, 40 views 64 px wide) in `format` (colmap,
/// transforms) and `layout` (object, studio), with `extra` flags.
fn synth_capture(scene: &std::path::Path, format: &str, layout: &str, extra: &[&str]) {
    let mut args = vec![
        "data",
        "synth",
        "--format",
        format,
        "--layout",
        layout,
        "--out",
        s(scene),
        "--size",
        "64",
        "--views",
        "40",
    ];
    args.extend_from_slice(extra);
    ok(cli(&args));
}

/// What `data check` prints about `scene`.
fn check_report(scene: &std::path::Path) -> String {
    let o = ok(cli(&["data", "check", s(scene), "--no-sheet"]));
    String::from_utf8_lossy(&o.stdout).to_string()
}

#[test]
fn a_capture_with_background_checks_and_trains() {
    let dir = tempfile::tempdir().unwrap();
    for (format, extra) in [("colmap", vec!["--text"]), ("transforms", vec![])] {
        let scene = dir.path().join(format);
        synth_capture(&scene, format, "object", &extra);
        let text = check_report(&scene);
        assert!(text.contains(&format!("({format})")), "{text}");
        assert!(text.contains("object-centred, unbounded"), "{text}");
        assert!(text.contains("lens     Polynomial"), "{text}");
    }
    let run = dir.path().join("run");
    let mean = train_and_evaluate(&dir.path().join("colmap"), &run);
    // The run says how it framed the capture.
    let frame: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("scene.json")).unwrap()).unwrap();
    assert_eq!(frame["summary"]["format"], "colmap");
    assert!(
        frame["to_scene"]["scale"].as_f64().unwrap() > 0.0,
        "{frame}"
    );
    let psnr = mean["psnr"].as_f64().expect("psnr in the mean line");
    assert!(psnr > CAPTURE_PSNR_BAR, "held-out PSNR {psnr} dB: {mean}");
    // A capture that now frames otherwise than when the run trained (here: the record says
    // another contraction) is refused, not rendered as noise.
    let mut frame = frame;
    frame["contraction"]["radius"] = 3.0.into();
    std::fs::write(run.join("scene.json"), frame.to_string()).unwrap();
    let o = cli(&["eval", "nerf", "--run", s(&run), "--backend", "flex"]);
    assert_clean_failure(&o, "framed differently");
}

/// Objects before a plain backdrop (the `studio` layout: sparse points on the objects alone)
/// are framed in a box, and the backdrop is learned as the background colour instead of being
/// painted as haze in front of the cameras. Measured with `NERF_SMALL` (seeds 0–2, this
/// project's 2-core AMD EPYC, 2026-11-27): held-out PSNR 22.65 / 21.88 / 21.87 dB, SSIM 0.905
/// / 0.891 / 0.893, the learned colour within 0.003 of the backdrop; the same capture
/// contracted with a black background (the framing before): 21.38 / 21.96 / 22.29 dB, SSIM
/// 0.848 / 0.874 / 0.847, haze in every depth map. PSNR, dominated by the plain backdrop, hardly
/// tells them apart; SSIM and the colour do.
#[test]
fn a_capture_before_a_plain_backdrop_learns_it_as_the_background() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("studio");
    synth_capture(&scene, "colmap", "studio", &[]);
    let text = check_report(&scene);
    assert!(text.contains("object-centred: box of half side"), "{text}");
    let run = dir.path().join("run");
    let mean = train_and_evaluate(&scene, &run);
    let (psnr, ssim) = (
        mean["psnr"].as_f64().unwrap(),
        mean["ssim"].as_f64().unwrap(),
    );
    assert!(
        psnr > 21.0 && ssim > 0.88,
        "held-out PSNR {psnr} dB, SSIM {ssim}: {mean}"
    );
    let loaded = ins_models::nerf::NerfRun::load(&run, &burn::prelude::Device::flex()).unwrap();
    let backdrop = ins_scene::data::synthetic::AnalyticScene::studio().backdrop;
    let learned = loaded.background();
    for (l, b) in learned.iter().zip(backdrop.to_array()) {
        assert!(
            (l - b).abs() < 0.02,
            "learned background {learned:?}, backdrop {backdrop:?}"
        );
    }
}

/// Writes a `transforms.json` capture of `layout` without its sparse points (as Polycam or
/// Record3D export them) into `dir/name` and returns it with `data check`'s report.
fn capture_without_points(dir: &std::path::Path, layout: &str) -> (std::path::PathBuf, String) {
    let scene = dir.join(layout);
    synth_capture(&scene, "transforms", layout, &[]);
    let json = scene.join("transforms.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let ply = doc.as_object_mut().unwrap().remove("ply_file_path");
    assert!(
        ply.is_some(),
        "the synthetic capture names its points: {doc}"
    );
    std::fs::write(&json, doc.to_string()).unwrap();
    let report = check_report(&scene);
    (scene, report)
}

/// Without sparse points, only the photos say how large a capture's box must be. Before a plain
/// backdrop it is the box the photos all keep in view: the `studio` layout gets half side 3
/// instead of the cameras' box of 6. Measured with `NERF_SMALL` (seeds 0–1, this project's
/// 2-core AMD EPYC, 2026-11-27): held-out PSNR 24.74 / 24.83 dB, SSIM 0.939 / 0.941; in the
/// box of 6: 23.74 / 23.39 dB, SSIM 0.920 / 0.909. A room's walls at the edges keep the box of
/// 6 (in the tight box the room capture lost 2.2–3.2 dB).
#[test]
fn a_capture_without_points_before_a_backdrop_gets_the_box_its_photos_share() {
    let dir = tempfile::tempdir().unwrap();
    let (_, text) = capture_without_points(dir.path(), "object");
    assert!(text.contains("not a plain backdrop"), "{text}");
    assert!(text.contains("box of half side 6.00"), "{text}");

    let (studio, text) = capture_without_points(dir.path(), "studio");
    assert!(text.contains("edges    a plain backdrop"), "{text}");
    assert!(text.contains("box of half side 3.00"), "{text}");
    let run = dir.path().join("run");
    let mean = train_and_evaluate(&studio, &run);
    let psnr = mean["psnr"].as_f64().unwrap();
    assert!(psnr > 24.2, "held-out PSNR {psnr} dB: {mean}");

    // The run recorded its box: a run that trained in another (as this capture was framed
    // before) is refused rather than queried in the wrong box.
    let path = run.join("scene.json");
    let mut frame: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(frame["bounds"]["max"][0].as_f64(), Some(3.0), "{frame}");
    frame["bounds"]["max"] = serde_json::json!([6.0, 6.0, 6.0]);
    frame["bounds"]["min"] = serde_json::json!([-6.0, -6.0, -6.0]);
    std::fs::write(&path, frame.to_string()).unwrap();
    let o = cli(&["eval", "nerf", "--run", s(&run), "--backend", "flex"]);
    assert_clean_failure(&o, "framed differently");
}

/// Photos whose poses are wrong (structure from motion placed 6 of the phone-like lego
/// capture's 44 across the object, turned half a turn; a phone's tracking drifts) are found by
/// the audit after 30 % of pretraining, named, and left out, and no other photo is. Here four
/// training photos of the studio capture are turned 35° about the vertical, in place. Measured
/// with `NERF_SMALL` (this project's 2-core AMD EPYC, 2026-11-27): the four fit at 12.5–14.6
/// dB against a median of 22.0 and are the four left out; held-out PSNR 22.18 / 21.69 dB (seeds
/// 0 / 1) against 20.91 / 20.92 keeping them. (The same turn in the room capture goes
/// unnoticed: there the four fit at 19.0–21.9 dB, within the others' 17.6–22.3.)
#[test]
fn misposed_photos_are_found_and_left_out() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("capture");
    synth_capture(&scene, "transforms", "studio", &[]);
    let json = scene.join("transforms.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let frames = doc["frames"].as_array_mut().unwrap();
    let pose = |f: &serde_json::Value| -> [[f64; 4]; 3] {
        std::array::from_fn(|r| {
            std::array::from_fn(|c| f["transform_matrix"][r][c].as_f64().unwrap())
        })
    };
    let up: [f64; 3] = {
        let u: [f64; 3] = std::array::from_fn(|r| frames.iter().map(|f| pose(f)[r][1]).sum());
        let len = u.iter().map(|x| x * x).sum::<f64>().sqrt();
        u.map(|x| x / len)
    };
    // Rodrigues: the rotation by `a` about the unit axis `up`.
    let a = 35f64.to_radians();
    let cross = [
        [0.0, -up[2], up[1]],
        [up[2], 0.0, -up[0]],
        [-up[1], up[0], 0.0],
    ];
    let turn = |r: usize, c: usize| {
        let id = if r == c { 1.0 } else { 0.0 };
        a.cos() * id + a.sin() * cross[r][c] + (1.0 - a.cos()) * up[r] * up[c]
    };
    // Training photos (every 8th, from the first, is held out).
    let names: Vec<String> = [3, 12, 21, 30]
        .map(|i| format!("frame_{i:05}.png"))
        .to_vec();
    let mut turned = 0;
    for f in frames.iter_mut() {
        let path = f["file_path"].as_str().unwrap().to_string();
        if !names
            .iter()
            .any(|n| n.starts_with(path.rsplit('/').next().unwrap()))
        {
            continue;
        }
        let p = pose(f);
        let mut m = [[0.0f64; 4]; 4];
        m[3][3] = 1.0;
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] = (0..3).map(|k| turn(r, k) * p[k][c]).sum();
            }
            m[r][3] = p[r][3];
        }
        f["transform_matrix"] = serde_json::json!(m);
        turned += 1;
    }
    assert_eq!(turned, names.len());
    std::fs::write(&json, doc.to_string()).unwrap();

    let run = dir.path().join("run");
    let mut args = vec!["train", "nerf", "--scene", s(&scene), "--out", s(&run)];
    args.extend_from_slice(NERF_SMALL);
    let err = stderr(&ok(cli(&args)));
    let line = err
        .lines()
        .find(|l| l.contains("their poses are likely wrong"))
        .unwrap_or_else(|| panic!("no photo was left out: {err}"));
    assert!(line.starts_with("4 of 35 training photos"), "{line}");
    for name in &names {
        assert!(line.contains(name.as_str()), "{name} not named: {line}");
    }
    let metrics = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    assert!(metrics.contains("\"dropped_views\":4.0"), "{metrics}");

    // The checkpoint keeps them out, and a stylization of the run leaves them out too.
    let dropped = |run: &std::path::Path| {
        let checkpoints = run.join("checkpoints");
        let latest = std::fs::read_to_string(checkpoints.join("latest")).unwrap();
        let bytes = std::fs::read(checkpoints.join(latest.trim()).join("task.bin")).unwrap();
        let mut views = ins_models::nerf::state_io::decode(&bytes)
            .unwrap()
            .dropped_views;
        views.sort();
        views
    };
    let left_out = dropped(&run);
    assert_eq!(left_out.len(), 4, "{left_out:?}");
    let stylized = stylize_nerf_briefly(&run, dir.path());
    assert_eq!(dropped(&stylized), left_out);
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

/// A COLMAP workspace whose photos live elsewhere trains with `--images`; without it the
/// missing folder is named; other formats refuse the flag.
#[test]
fn train_reads_a_colmap_workspaces_photos_from_images() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("ws");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "colmap",
        "--out",
        s(&scene),
        "--size",
        "24",
        "--views",
        "10",
    ]));
    let photos = dir.path().join("photos elsewhere");
    std::fs::rename(scene.join("images"), &photos).unwrap();
    let train = |extra: &[&str], out: &str| {
        let run = dir.path().join(out);
        let mut args = vec!["train", "nerf", "--scene", s(&scene), "--out", s(&run)];
        args.extend_from_slice(extra);
        args.extend_from_slice(NERF_TINY);
        (cli(&args), run)
    };
    let (o, _) = train(&[], "without");
    assert_clean_failure(&o, "images");
    let (o, run) = train(&["--images", s(&photos)], "with");
    ok(o);
    let config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["images"].as_str(), Some(s(&photos)), "{config}");
    // The run loads again (render) from the recorded folder.
    let png = dir.path().join("v.png");
    ok(cli(&[
        "render",
        "nerf",
        "--run",
        s(&run),
        "--view",
        "0",
        "--out",
        s(&png),
    ]));
    // Other formats name their own photos.
    let blender = synth_scene(&dir.path().join("b"), "blender", 16, 4);
    let o = cli(&[
        "train",
        "nerf",
        "--scene",
        s(&blender),
        "--images",
        s(&photos),
        "--out",
        s(&dir.path().join("no")),
        "--steps",
        "1",
        "--quiet",
    ]);
    assert_clean_failure(&o, "--images is for COLMAP");
}

/// Held-out silhouette IoU a 400-step IDR must reach on the synthetic room capture with masks
/// (transforms.json, 24 views of 48×36, 18 for training): measured 0.935 on this project's
/// 2-core machine (AMD EPYC Zen 4, 2026-11-27); the sphere placed from the cameras alone
/// (`--no-mask`), a surface trained without silhouettes, is not held to it.
const CAPTURE_IDR_IOU_BAR: f64 = 0.85;

/// IDR on a user's capture: a transforms.json with `mask_path`s is put in the unit sphere from
/// its masks' visual hull, reconstructed, and the frame it trained in is recorded and checked.
#[test]
fn a_masked_capture_trains_a_surface() {
    let dir = tempfile::tempdir().unwrap();
    let scene = synth_scene(&dir.path().join("t"), "transforms", 48, 24);
    let run = dir.path().join("surface");
    ok(cli(&[
        "train",
        "idr",
        "--renderer",
        "surface",
        "--scene",
        s(&scene),
        "--out",
        s(&run),
        "--steps",
        "400",
        "--rays",
        "1024",
        "--holdout",
        "4",
        "--grid-max-resolution",
        "1024",
        "--color-width",
        "64",
        "--eval-every",
        "0",
        "--quiet",
        "--backend",
        "flex",
    ]));
    let frame: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("scene.json")).unwrap()).unwrap();
    assert_eq!(frame["summary"]["format"], "transforms", "{frame}");
    assert!(frame["contraction"].is_null(), "{frame}");
    let o = ok(cli(&["eval", "idr", "--run", s(&run), "--backend", "flex"]));
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    let mean: serde_json::Value =
        serde_json::from_str(text.lines().last().expect("a mean line")).unwrap();
    let iou = mean["iou"].as_f64().expect("iou in the mean line");
    assert!(iou > CAPTURE_IDR_IOU_BAR, "held-out IoU {iou}: {text}");
    // Masks that no longer match the run's frame are refused, not rendered as noise.
    let mut frame = frame;
    frame["to_scene"]["scale"] = 9.0.into();
    std::fs::write(run.join("scene.json"), frame.to_string()).unwrap();
    let o = cli(&["eval", "idr", "--run", s(&run), "--backend", "flex"]);
    assert_clean_failure(&o, "framed differently");
}
