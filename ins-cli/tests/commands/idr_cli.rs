//! `ins-cli train/render/eval idr`, `export mesh` and `eval mesh` as a user meets them, on a
//! small DTU scene written by `ins-cli data synth`, and the bad inputs that must end in one
//! clear message with nothing written over.

use crate::common::*;

#[test]
fn train_render_eval_export_and_refuse_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("dtu");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "dtu",
        "--out",
        s(&scene),
        "--size",
        "24",
        "--views",
        "8",
    ]));
    let run = dir.path().join("run");
    let trained = ok(cli(&[
        "train",
        "idr",
        "--scene",
        s(&scene),
        "--holdout",
        "4",
        "--steps",
        "20",
        "--rays",
        "256",
        "--eval-every",
        "10",
        "--checkpoint-every",
        "10",
        "--out",
        s(&run),
        "--quiet",
        "--backend",
        "flex",
    ]));
    for f in [
        "config.json",
        "metrics.jsonl",
        "loss_curve.png",
        "val/final.png",
        "val/final.json",
    ] {
        assert!(run.join(f).exists(), "missing {f}");
    }
    let summary: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&trained.stdout).trim()).unwrap();

    // Render a view (colour and normals) and evaluate the held-out views as JSON lines.
    let png = dir.path().join("v.png");
    ok(cli(&[
        "render",
        "idr",
        "--run",
        s(&run),
        "--view",
        "1",
        "--out",
        s(&png),
    ]));
    assert_eq!(image::open(&png).unwrap().width(), 24);
    let normals = dir.path().join("n.png");
    ok(cli(&[
        "render",
        "idr",
        "--run",
        s(&run),
        "--view",
        "1",
        "--normals",
        "--out",
        s(&normals),
    ]));
    assert_ne!(
        std::fs::read(&png).unwrap(),
        std::fs::read(&normals).unwrap()
    );
    let o = ok(cli(&["eval", "idr", "--run", s(&run)]));
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 3, "two held-out views (0 and 4) and the mean");
    assert!(
        lines
            .iter()
            .all(|l| l["iou"].as_f64().is_some_and(|v| (0.0..=1.0).contains(&v)))
    );
    // The run's own final scores are those of the same held-out views.
    let (last, scored) = (&lines[2], &summary["final"]);
    assert_eq!(scored["views"].as_f64(), Some(2.0), "{summary}");
    for key in ["iou", "psnr_mask"] {
        let (a, b) = (last[key].as_f64().unwrap(), scored[key].as_f64().unwrap());
        assert!(
            (a - b).abs() < 1e-3,
            "{key}: eval idr {a}, the run's final {b}"
        );
    }
    let file: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("val/final.json")).unwrap()).unwrap();
    assert_eq!(&file, scored);

    // A mesh any viewer opens: a PLY header with vertices, faces and colours.
    let ply = dir.path().join("m.ply");
    ok(cli(&[
        "export",
        "mesh",
        "--run",
        s(&run),
        "--resolution",
        "32",
        "--out",
        s(&ply),
    ]));
    let bytes = std::fs::read(&ply).unwrap();
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(400)]);
    assert!(
        head.starts_with("ply") && head.contains("element vertex") && head.contains("element face"),
        "{head}"
    );
    assert!(head.contains("property uchar red"), "{head}");

    // The mesh scored against the true surface `data synth` wrote beside the photos, in the
    // world frame's units (the scene is written at 30 times the unit sphere).
    let reference = scene.join("reference.ply");
    let o = ok(cli(&[
        "eval",
        "mesh",
        "--run",
        s(&run),
        "--reference",
        s(&reference),
        "--resolution",
        "32",
        "--samples",
        "5000",
    ]));
    let score: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap();
    let f = |k: &str| score[k].as_f64().unwrap_or_else(|| panic!("{k}: {score}"));
    assert!((f("units_per_scene_unit") - 30.0).abs() < 1e-3, "{score}");
    assert!((f("max_distance") - 3.0).abs() < 1e-3, "{score}");
    assert!(f("reference_points") > 1000.0, "{score}");
    assert!((0.0..=1.0).contains(&f("fscore")), "{score}");
    assert!(
        f("chamfer") > 0.0 && f("chamfer") < f("max_distance"),
        "{score}"
    );
    // The same mesh written in the dataset's frame is where `eval mesh` puts the run's own:
    // scored against its vertices, every point of it lies within a tenth of the unit sphere.
    let world_ply = dir.path().join("world.ply");
    let o = ok(cli(&[
        "export",
        "mesh",
        "--run",
        s(&run),
        "--resolution",
        "32",
        "--frame",
        "world",
        "--out",
        s(&world_ply),
    ]));
    let exported: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(exported["frame"], "world");
    let o = ok(cli(&[
        "eval",
        "mesh",
        "--run",
        s(&run),
        "--reference",
        s(&world_ply),
        "--resolution",
        "32",
        "--samples",
        "5000",
        "--threshold",
        "3",
    ]));
    let own: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap();
    assert!(
        own["precision"].as_f64().unwrap() > 0.99 && own["surface_outliers"] == 0.0,
        "{own}"
    );
    // A reference that is missing or not a PLY: one message naming the file.
    let missing = dir.path().join("no_such_reference.ply");
    let corrupt = dir.path().join("corrupt_reference.ply");
    std::fs::write(&corrupt, "not a point cloud").unwrap();
    for bad in [&missing, &corrupt] {
        let o = cli(&["eval", "mesh", "--run", s(&run), "--reference", s(bad)]);
        assert_clean_failure(&o, bad.file_name().unwrap().to_str().unwrap());
    }

    // Bad input: a forward-facing scene, a scene without masks, a NeRF run, an absurd
    // resolution.
    let llff = dir.path().join("llff");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "llff",
        "--out",
        s(&llff),
        "--size",
        "16",
        "--views",
        "3",
    ]));
    let o = cli(&[
        "train",
        "idr",
        "--scene",
        s(&llff),
        "--out",
        s(&dir.path().join("x")),
    ]);
    assert_clean_failure(&o, "forward-facing");
    let unmasked = dir.path().join("unmasked");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "dtu",
        "--out",
        s(&unmasked),
        "--size",
        "16",
        "--views",
        "3",
    ]));
    std::fs::remove_dir_all(unmasked.join("mask")).unwrap();
    let o = cli(&[
        "train",
        "idr",
        "--scene",
        s(&unmasked),
        "--out",
        s(&dir.path().join("y")),
    ]);
    assert_clean_failure(&o, "--no-mask");
    // A hash grid finer than the encoding supports is refused before anything is written.
    let too_fine = dir.path().join("too_fine");
    let o = cli(&[
        "train",
        "idr",
        "--scene",
        s(&scene),
        "--grid-max-resolution",
        "5000",
        "--out",
        s(&too_fine),
    ]);
    assert_clean_failure(&o, "--grid-max-resolution 5000");
    assert!(!too_fine.join("config.json").exists());
    // So are a colour grid or an SDF table out of range, a share of rays that is not one, a
    // learning-rate decay that is not a fraction, no rounds of drawing samples and a
    // smoothness weight without the volume renderer.
    for (args, refused) in [
        (&["--color-grid", "4096"][..], "--color-grid 4096"),
        (&["--grid-table", "20"][..], "--grid-table 20"),
        (&["--mask-rays", "1.5"][..], "--mask-rays 1.5"),
        (&["--lr-decay", "0"][..], "--lr-decay 0"),
        (&["--upsample-rounds", "0"][..], "--upsample-rounds 0"),
        (
            &["--curvature-weight", "0.5", "--renderer", "surface"][..],
            "--curvature-weight 0.5",
        ),
    ] {
        let mut line = vec!["train", "idr", "--scene", s(&scene), "--out", s(&too_fine)];
        line.extend_from_slice(args);
        let o = cli(&line);
        assert_clean_failure(&o, refused);
        assert!(!too_fine.join("config.json").exists());
    }
    let nerf_like = dir.path().join("nerf_like");
    std::fs::create_dir_all(&nerf_like).unwrap();
    std::fs::write(
        nerf_like.join("config.json"),
        br#"{"scene": "s", "cim": "grid"}"#,
    )
    .unwrap();
    let o = cli(&[
        "render",
        "idr",
        "--run",
        s(&nerf_like),
        "--view",
        "0",
        "--out",
        s(&png),
    ]);
    assert_clean_failure(&o, "not an IDR run");
    let before = std::fs::read(&ply).unwrap();
    let o = cli(&[
        "export",
        "mesh",
        "--run",
        s(&run),
        "--resolution",
        "4096",
        "--out",
        s(&ply),
    ]);
    assert_clean_failure(&o, "GB");
    assert_eq!(
        std::fs::read(&ply).unwrap(),
        before,
        "the refused export wrote over the mesh"
    );
}

#[test]
fn bench_idr_pretrain_reports_a_step_time_and_its_rays() {
    let o = cli(&["bench", "idr-pretrain", "--steps", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let line: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(line["workload"], "idr-pretrain");
    let ms = line["ms_per_step"].as_f64().unwrap();
    assert!(ms > 0.0, "{line}");
    // On flex a read costs nothing, so steps back to back are not timed apart.
    assert!(line.get("pipelined_ms_per_step").is_none(), "{line}");
    // 512 rays (the volume renderer's pretraining default) in that time.
    let rays_per_s = line["rays_per_s"].as_f64().unwrap();
    assert!(
        (rays_per_s - 512.0 / ms * 1e3).abs() <= 0.01 * rays_per_s + 1.0,
        "{line}"
    );
}

#[test]
fn a_stylized_surface_is_evaluated_along_its_capture_arc_with_its_texture_on_the_object() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("dtu");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "dtu",
        "--out",
        s(&scene),
        "--size",
        "32",
        "--views",
        "8",
    ]));
    let run = dir.path().join("run");
    ok(cli(&[
        "train",
        "idr",
        "--renderer",
        "surface",
        "--scene",
        s(&scene),
        "--steps",
        "30",
        "--rays",
        "256",
        "--eval-every",
        "0",
        "--out",
        s(&run),
        "--quiet",
        "--backend",
        "flex",
    ]));
    let painting = dir.path().join("stripes.png");
    image::RgbImage::from_fn(48, 48, |x, y| {
        if ((x + y) / 4) % 2 == 0 {
            image::Rgb([230, 30, 30])
        } else {
            image::Rgb([30, 50, 230])
        }
    })
    .save(&painting)
    .unwrap();
    let styled = dir.path().join("styled");
    let o = ok(cli(&[
        "train",
        "idr",
        "--from",
        s(&run),
        "--style",
        s(&painting),
        "--steps",
        "6",
        "--patch",
        "16",
        "--stride",
        "1",
        "--style-size",
        "48",
        "--out",
        s(&styled),
        "--quiet",
        "--backend",
        "flex",
    ]));
    // The stylization watches its renders for a collapse to pure colours (none here).
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let saturated = summary["last"]["saturated"].as_f64();
    assert!(
        saturated.is_some_and(|v| (0.0..0.5).contains(&v)),
        "{summary}"
    );
    let out = dir.path().join("eval");
    let o = ok(cli(&[
        "eval",
        "consistency",
        "--run",
        s(&styled),
        "--frames",
        "9",
        "--reference-views",
        "2",
        "--reference-steps",
        "4",
        "--out",
        s(&out),
        "--quiet",
        "--backend",
        "flex",
    ]));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    // DTU's cameras see one side: the path sweeps that side, not the unseen back.
    assert_eq!(summary["path"], "arc");
    // The surface is frozen: the stylized run sees the object where the pretrained one does.
    assert_eq!(
        summary["opacity_agreement"].as_f64(),
        Some(1.0),
        "{summary}"
    );
    let sets = summary["texture"]["sets"].as_array().unwrap();
    let names: Vec<&str> = sets.iter().map(|s| s["set"].as_str().unwrap()).collect();
    assert_eq!(names, ["pretrained", "stylized", "reference2d"]);
    for set in sets {
        for l in ["relu1_2", "relu2_2", "relu3_3", "relu4_3"] {
            let d = set[format!("nn_{l}")].as_f64().unwrap();
            assert!((0.0..=2.0).contains(&d), "{set}");
        }
    }
    // By definition the pretrained frames are at 0 and the reference at 1 where defined.
    let pre = &sets[0];
    let reference = &sets[2];
    for l in ["relu1_2", "relu2_2", "relu3_3", "relu4_3"] {
        let key = format!("transfer_{l}");
        if let (Some(p), Some(r)) = (pre[&key].as_f64(), reference[&key].as_f64()) {
            assert_eq!((p, r), (0.0, 1.0), "{key}");
        }
    }
    assert!(out.join("strength_consistency.png").is_file());
    assert!(out.join("reference2d").join("frame_0002.png").is_file());
    assert!(String::from_utf8_lossy(&o.stdout).contains("rmse_k1"));
}
