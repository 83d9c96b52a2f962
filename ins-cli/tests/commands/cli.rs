//! The command line as a user meets it: a quick run on the built-in input, rendering, VGG
//! features, and bad input that must end in one clear message naming the file, never a panic.

use std::path::{Path, PathBuf};

use crate::common::*;

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/fixtures")
        .join(rel)
}

#[test]
fn quick_run_on_the_builtin_input_then_render_any_size_and_mix() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let o = cli(&[
        "train",
        "siren",
        "--out",
        r,
        "--size",
        "32",
        "--steps",
        "20",
        "--quiet",
        "--backend",
        "flex",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["steps"], 20);
    // Its stylization phase watches the renders for a collapse to pure colours (none here).
    let saturated = summary["last"]["saturated"].as_f64();
    assert!(
        saturated.is_some_and(|v| (0.0..0.5).contains(&v)),
        "{summary}"
    );
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    assert_eq!(summary["warnings"], serde_json::json!([]), "{summary}");
    for f in [
        "stylized.png",
        "preview.png",
        "loss_curve.png",
        "metrics.jsonl",
        "config.json",
        "inputs/demo_content.png",
        "inputs/bridgewater_madonna.png",
    ] {
        assert!(run.join(f).exists(), "missing {f}");
    }
    let out = dir.path().join("big.png");
    let o = cli(&[
        "render",
        "siren",
        "--run",
        r,
        "--size",
        "96x64",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&out).unwrap();
    assert_eq!((img.width(), img.height()), (96, 64));
    // One style: a mix of two weights is refused with a reason.
    let o = cli(&[
        "render",
        "siren",
        "--run",
        r,
        "--mix",
        "1,1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, "2 weights");
    // Continuing a finished run is refused unless --resume.
    let o = cli(&[
        "train", "siren", "--out", r, "--size", "32", "--steps", "20", "--quiet",
    ]);
    assert_clean_failure(&o, "--resume");
}

#[test]
fn missing_content_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let o = cli(&[
        "train",
        "siren",
        "--content",
        "/no/such/photo.jpg",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_clean_failure(&o, "/no/such/photo.jpg");
}

#[test]
fn corrupt_style_image_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("painting.png");
    std::fs::write(&bad, b"\x89PNG\r\n\x1a\n but then nothing sensible").unwrap();
    let o = cli(&[
        "train",
        "siren",
        "--style",
        bad.to_str().unwrap(),
        "--out",
        dir.path().join("r").to_str().unwrap(),
        "--steps",
        "2",
    ]);
    assert_clean_failure(&o, "painting.png");
}

#[test]
fn wrong_onnx_model_names_the_file_and_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let onnx = fixture("vgg/too_few.onnx");
    let o = cli(&[
        "train",
        "siren",
        "--onnx",
        onnx.to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
        "--steps",
        "2",
    ]);
    assert_clean_failure(&o, "too_few.onnx");
    assert!(
        stderr(&o).contains("expected [64, 3, 3, 3]"),
        "{}",
        stderr(&o)
    );
    let garbage = dir.path().join("weights.onnx");
    std::fs::write(&garbage, vec![0xffu8; 1000]).unwrap();
    let o = cli(&["vgg", "info", "--onnx", garbage.to_str().unwrap()]);
    assert_clean_failure(&o, "weights.onnx");
}

#[test]
fn overflowing_loss_weight_stops_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let o = cli(&[
        "train",
        "siren",
        "--out",
        run.to_str().unwrap(),
        "--size",
        "24",
        "--fit-steps",
        "2",
        "--stylize-steps",
        "4",
        "--style-weight",
        "1e40",
        "--quiet",
    ]);
    assert_clean_failure(&o, "too large");
}

#[test]
fn vgg_features_writes_the_four_layers() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("img.png");
    image::RgbImage::from_fn(40, 24, |x, y| {
        image::Rgb([(x * 6) as u8, (y * 10) as u8, 128])
    })
    .save(&img)
    .unwrap();
    let out = dir.path().join("feats");
    let o = cli(&[
        "vgg",
        "features",
        "--image",
        img.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--backend",
        "flex",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let expect = [
        ("relu1_2", [1, 64, 24, 40]),
        ("relu2_2", [1, 128, 12, 20]),
        ("relu3_3", [1, 256, 6, 10]),
        ("relu4_3", [1, 512, 3, 5]),
    ];
    for (name, shape) in expect {
        let bytes = std::fs::read(out.join(format!("{name}.npy"))).unwrap();
        let header = String::from_utf8_lossy(&bytes[..128]).to_string();
        let want = format!("({}, {}, {}, {}, )", shape[0], shape[1], shape[2], shape[3]);
        assert!(header.contains(&want), "{name}: {header}");
        assert!(header.contains("<f4"), "{name}: {header}");
    }
}

#[test]
fn render_of_a_missing_run_is_a_clear_error() {
    let o = cli(&[
        "render",
        "siren",
        "--run",
        "/no/such/run",
        "--out",
        "/tmp/x.png",
    ]);
    assert_clean_failure(&o, "/no/such/run");
    // The design's old name for the CPU backend runs flex, saying so once.
    let o = cli(&[
        "export",
        "mesh",
        "--run",
        "/no/such/run",
        "--backend",
        "ndarray",
        "--out",
        "/tmp/x.ply",
    ]);
    assert_clean_failure(&o, "/no/such/run");
    assert_eq!(
        stderr(&o).matches("running on flex").count(),
        1,
        "{}",
        stderr(&o)
    );
}

/// `--backend cuda` where CUDA cannot run stops before the run starts, with one line naming
/// what is missing and the other backends. `CUDA_PATH` points at an empty folder, so a machine
/// with NVIDIA's driver and a GPU stops at the headers, and one without (CI) at the driver.
#[test]
fn cuda_where_it_cannot_run_names_what_is_missing_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_ins-cli"))
        .args(["train", "siren", "--steps", "2", "--backend", "cuda"])
        .arg("--out")
        .arg(&out)
        .env("CUDA_PATH", dir.path())
        .output()
        .expect("running ins-cli");
    assert_clean_failure(&o, "--backend cuda: ");
    let e = stderr(&o);
    assert!(
        e.contains("no NVIDIA driver (libcuda.so)") || e.contains("has no cuda_runtime.h"),
        "{e}"
    );
    assert!(
        e.contains("--backend flex") && e.contains("--backend wgpu"),
        "{e}"
    );
    assert!(!out.exists(), "a failed start wrote {}", out.display());
}

#[test]
fn two_styles_train_and_render_a_mix_and_a_strip() {
    let dir = tempfile::tempdir().unwrap();
    let s1 = dir.path().join("s1.png");
    let s2 = dir.path().join("s2.png");
    image::RgbImage::from_fn(32, 32, |x, _| {
        image::Rgb([if x % 8 < 4 { 250 } else { 20 }, 30, 30])
    })
    .save(&s1)
    .unwrap();
    image::RgbImage::from_fn(32, 32, |_, y| {
        image::Rgb([30, 30, if y % 6 < 3 { 250 } else { 20 }])
    })
    .save(&s2)
    .unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let o = cli(&[
        "train",
        "siren",
        "--style",
        s1.to_str().unwrap(),
        "--style",
        s2.to_str().unwrap(),
        "--out",
        r,
        "--size",
        "24",
        "--steps",
        "10",
        "--quiet",
        "--backend",
        "flex",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(run.join("stylized_0.png").exists() && run.join("stylized_1.png").exists());
    let strip = dir.path().join("strip.png");
    let o = cli(&[
        "render",
        "siren",
        "--run",
        r,
        "--strip",
        "4",
        "--size",
        "20x20",
        "--out",
        strip.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&strip).unwrap();
    assert_eq!(
        (img.width(), img.height()),
        (80, 20),
        "four 20×20 renders side by side"
    );
    let mix = dir.path().join("mix.png");
    let o = cli(&[
        "render",
        "siren",
        "--run",
        r,
        "--mix",
        "0.3,0.7",
        "--out",
        mix.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cli(&[
        "render",
        "siren",
        "--run",
        r,
        "--mix=-1,2",
        "--out",
        mix.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, "non-negative");
}

/// `--precision bf16` runs VGG in bf16 where the CPU has AMX or AVX-512 BF16 (features close
/// to f32's, not equal), and with both forced off (`INS_DISABLE_BF16=1`, as on a CPU without
/// them) says so and gives exactly the f32 features.
#[test]
fn bf16_precision_runs_where_the_cpu_can_or_falls_back_to_f32() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("img.png");
    image::RgbImage::from_fn(48, 40, |x, y| {
        image::Rgb([(x * 5) as u8, (y * 6) as u8, ((x * y) % 255) as u8])
    })
    .save(&img)
    .unwrap();
    let features = |precision: &str, bf16_off: bool| {
        let out = dir.path().join(format!("{precision}_{bf16_off}"));
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_ins-cli"));
        c.args(["vgg", "features", "--image", s(&img), "--out", s(&out)])
            .args(["--backend", "flex", "--precision", precision])
            .env("INS_NO_GPU", "1");
        if bf16_off {
            c.env(ins_conv::dpbf16::DISABLE_ENV, "1");
        }
        let o = ok(c.output().expect("running ins-cli"));
        let layer = std::fs::read(out.join("relu4_3.npy")).unwrap();
        (layer, stderr(&o))
    };
    let (f32_layer, _) = features("f32", false);
    let (off_layer, off_msg) = features("bf16", true);
    assert!(off_msg.contains("VGG runs in f32"), "{off_msg}");
    assert_eq!(off_layer, f32_layer, "the fallback is not f32");
    let (bf16_layer, msg) = features("bf16", false);
    if ins_conv::Precision::Bf16.effective() == ins_conv::Precision::Bf16 {
        assert!(msg.contains("VGG convolutions in bf16"), "{msg}");
        assert_ne!(bf16_layer, f32_layer, "bf16 gave f32's exact features");
        let read = |b: &[u8]| -> Vec<f32> {
            // .npy v1: magic (6), version (2), header length (u16 LE), header, data.
            let data = 10 + u16::from_le_bytes([b[8], b[9]]) as usize;
            b[data..]
                .chunks(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect()
        };
        let (a, b) = (read(&bf16_layer), read(&f32_layer));
        let scale = b.iter().fold(1e-3f32, |m, v| m.max(v.abs()));
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
            / scale;
        assert!(
            worst < 2e-2,
            "bf16 relu4_3 off by {worst} of its largest value"
        );
    } else {
        assert_eq!(bf16_layer, f32_layer);
    }
}
