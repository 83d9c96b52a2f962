//! `ins-cli train/render/eval idr` and `export mesh` as a user meets them, on a small DTU scene
//! written by `ins-cli data synth`, and the bad inputs that must end in one clear message with
//! nothing written over.

mod common;
use common::*;

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
    ok(cli(&[
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
    ] {
        assert!(run.join(f).exists(), "missing {f}");
    }

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

    // Bad input: a Blender scene, a scene without masks, a NeRF run, an absurd resolution.
    let blender = dir.path().join("blender");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "blender",
        "--out",
        s(&blender),
        "--size",
        "16",
        "--views",
        "3",
    ]));
    let o = cli(&[
        "train",
        "idr",
        "--scene",
        s(&blender),
        "--out",
        s(&dir.path().join("x")),
    ]);
    assert_clean_failure(&o, "DTU");
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
    // So are a colour grid out of range, a share of rays that is not one and a learning-rate
    // decay that is not a fraction.
    for (flag, value) in [
        ("--color-grid", "4096"),
        ("--mask-rays", "1.5"),
        ("--lr-decay", "0"),
    ] {
        let o = cli(&[
            "train",
            "idr",
            "--scene",
            s(&scene),
            flag,
            value,
            "--out",
            s(&too_fine),
        ]);
        assert_clean_failure(&o, &format!("{flag} {value}"));
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
    // 2048 rays (the pretraining default) in that time.
    let rays_per_s = line["rays_per_s"].as_f64().unwrap();
    assert!(
        (rays_per_s - 2048.0 / ms * 1e3).abs() <= 0.01 * rays_per_s + 1.0,
        "{line}"
    );
}
