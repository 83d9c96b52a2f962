//! `ins-cli eval consistency` and `ins-cli report` on a tiny stylized run of a synthetic scene,
//! and the report opened in a real headless browser (Chromium, which `scripts/setup.sh`
//! installs): every picture on the page must load.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::*;

/// A pretrained (about ten seconds) and a stylized NeRF run on a 32 px synthetic Blender scene.
fn stylized_run(dir: &Path) -> PathBuf {
    let scene = dir.join("scene");
    ok(cli(&[
        "data",
        "synth",
        "--format",
        "blender",
        "--out",
        s(&scene),
        "--size",
        "32",
        "--views",
        "6",
    ]));
    let run = dir.join("run");
    // Enough steps for a surface to form (the views must have depth to warp by).
    ok(cli(&[
        "train",
        "nerf",
        "--scene",
        s(&scene),
        "--out",
        s(&run),
        "--steps",
        "200",
        "--target-samples",
        "16384",
        "--log2-table",
        "14",
        "--max-resolution",
        "128",
        "--occupancy-resolution",
        "32",
        "--eval-every",
        "0",
        "--quiet",
        "--backend",
        "flex",
    ]));
    let style = dir.join("style.png");
    image::RgbImage::from_fn(32, 32, |x, y| {
        image::Rgb([(x * 8) as u8, (y * 8) as u8, ((x ^ y) * 8) as u8])
    })
    .save(&style)
    .unwrap();
    let st = dir.join("stylized");
    ok(stylize_nerf(
        &run,
        &[&style],
        &st,
        &["--steps", "4", "--patch", "16", "--style-size", "32"],
    ));
    st
}

/// The `src` and `href` targets of a page.
fn references(html: &str) -> Vec<String> {
    let mut out = Vec::new();
    for attr in ["src=\"", "href=\""] {
        let mut rest = html;
        while let Some(i) = rest.find(attr) {
            rest = &rest[i + attr.len()..];
            let end = rest.find('"').unwrap();
            out.push(rest[..end].to_string());
        }
    }
    out
}

/// A headless Chromium: `$INS_CHROMIUM`, else the first of the system's names on PATH.
fn chromium() -> PathBuf {
    if let Some(p) = std::env::var_os("INS_CHROMIUM") {
        return p.into();
    }
    for name in [
        "chromium-headless-shell",
        "chromium",
        "chromium-browser",
        "google-chrome",
    ] {
        if let Ok(o) = Command::new("which").arg(name).output()
            && o.status.success()
        {
            return String::from_utf8_lossy(&o.stdout).trim().into();
        }
    }
    panic!(
        "no headless Chromium on PATH: run scripts/setup.sh (it installs \
         chromium-headless-shell) or set INS_CHROMIUM"
    );
}

fn browser(args: &[&str]) -> std::process::Output {
    Command::new(chromium())
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            // WebGL on the CPU (SwiftShader) for the mesh's 3D view.
            "--enable-unsafe-swiftshader",
            "--disable-dev-shm-usage",
            "--disable-background-networking",
            "--no-first-run",
            "--virtual-time-budget=10000",
        ])
        .args(args)
        .output()
        .expect("running Chromium")
}

#[test]
fn consistency_eval_and_report_open_in_a_browser() {
    let dir = tempfile::tempdir().unwrap();
    let st = stylized_run(dir.path());

    // A pretrained run is refused, naming what is needed.
    let o = cli(&[
        "eval",
        "consistency",
        "--run",
        s(&dir.path().join("run")),
        "--backend",
        "flex",
    ]);
    assert_clean_failure(&o, "stylized run");
    let o = cli(&[
        "eval",
        "consistency",
        "--run",
        s(&st),
        "--frames",
        "5",
        "--backend",
        "flex",
    ]);
    assert_clean_failure(&o, "--frames 5");

    let eval = [
        "eval",
        "consistency",
        "--run",
        s(&st),
        "--frames",
        "10",
        "--baseline2d",
        "--baseline-steps",
        "3",
        "--quiet",
        "--backend",
        "flex",
    ];
    let o = ok(cli(&eval));
    let stdout = String::from_utf8_lossy(&o.stdout);
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let sets: Vec<&str> = lines.iter().filter_map(|l| l["set"].as_str()).collect();
    assert_eq!(sets, ["stylized", "baseline2d", "pretrained"]);
    let eval_dir = st.join("consistency");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(eval_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["frames"], 10);
    // The pretrained frames compared with themselves are the floor: defined and small, and a
    // set compared against its own renders has zero content distance.
    let floor = &summary["sets"][2];
    assert!(floor["rmse_k1"].as_f64().unwrap() < 0.2, "{floor}");
    assert_eq!(floor["content_distance"].as_f64().unwrap(), 0.0);
    assert!(summary["baseline_over_stylized_k1"].as_f64().is_some());
    let pairs = std::fs::read_to_string(eval_dir.join("pairs.jsonl")).unwrap();
    // 3 sets × (9 pairs at k=1 + 3 at k=7).
    assert_eq!(pairs.lines().count(), 3 * (9 + 3));
    for f in [
        "stylized/frame_0009.png",
        "baseline2d/frame_0009.png",
        "stylized.gif",
        "baseline2d.gif",
        "depth_stylized.png",
        "views.jsonl",
    ] {
        assert!(eval_dir.join(f).is_file(), "{f} missing");
    }

    // A rerun keeps the finished baseline frames.
    let o = ok(cli(&eval));
    assert!(stderr(&o).contains("exists, kept"), "{}", stderr(&o));

    let report = dir.path().join("report");
    ok(cli(&["report", "--run", s(&st), "--out", s(&report)]));
    let index = report.join("index.html");
    let html = std::fs::read_to_string(&index).unwrap();
    let refs = references(&html);
    assert!(refs.len() >= 8, "{refs:?}");
    for r in &refs {
        assert!(
            report.join(r).is_file(),
            "the page references {r}, which is not there"
        );
    }
    assert!(html.contains("baseline2d.gif") && html.contains("RMSE k=7"));

    // In a real browser every picture loads.
    let url = format!("file://{}", index.canonicalize().unwrap().display());
    let o = browser(&["--dump-dom", &url]);
    let dom = String::from_utf8_lossy(&o.stdout);
    assert!(
        dom.contains("data-images=\"ok\""),
        "images did not all load: {}\n{}",
        dom.chars().take(400).collect::<String>(),
        String::from_utf8_lossy(&o.stderr)
    );
    // The mesh's 3D view drew the exported glTF.
    assert!(report.join("mesh.glb").is_file() && report.join("mesh.js").is_file());
    assert!(
        dom.contains("data-mesh=\"ok "),
        "the 3D view did not draw: {}",
        dom.split("data-mesh=")
            .nth(1)
            .unwrap_or("(no canvas)")
            .chars()
            .take(200)
            .collect::<String>()
    );
    let shot = dir.path().join("shot.png");
    let o = browser(&[
        &format!("--screenshot={}", shot.display()),
        "--window-size=1100,1400",
        &url,
    ]);
    assert!(shot.is_file(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&shot).unwrap().to_rgb8();
    let distinct: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    assert!(
        distinct.len() > 50,
        "a blank screenshot ({} colours)",
        distinct.len()
    );

    // A broken page is caught by the same check: remove one picture.
    std::fs::remove_file(report.join("painting.png")).unwrap();
    let o = browser(&["--dump-dom", &url]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("broken:painting.png"));

    // A folder that is not a report is not written over.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let o = cli(&["report", "--run", s(&st), "--out", s(&other)]);
    assert_clean_failure(&o, "not a report");
    assert_eq!(
        std::fs::read_to_string(other.join("notes.txt")).unwrap(),
        "mine"
    );
}
