//! What every CLI test does: run `ins-cli` (no GPU probing), read its stderr, and check that a
//! failure is one clear message, never a panic.

use std::path::Path;
use std::process::{Command, Output};

/// Runs `ins-cli args…` to completion.
pub fn cli(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ins-cli"))
        .args(args)
        .env("INS_NO_GPU", "1")
        .output()
        .expect("running ins-cli")
}

/// The command's stderr as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// `o`, after asserting it succeeded (its stderr otherwise).
pub fn ok(o: Output) -> Output {
    assert!(o.status.success(), "{}", stderr(&o));
    o
}

/// The command failed with exit status 1 (2: a usage error caught by the argument parser) and
/// a message naming `needle`, with no panic output.
pub fn assert_clean_failure(o: &Output, needle: &str) {
    let e = stderr(o);
    assert!(
        matches!(o.status.code(), Some(1 | 2)),
        "exit status {:?}, stderr: {e}",
        o.status
    );
    assert!(e.contains(needle), "stderr does not name {needle:?}: {e}");
    assert!(
        !e.contains("panicked") && !e.contains("RUST_BACKTRACE") && !e.contains("internal failure"),
        "panic output: {e}"
    );
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Flags of a tiny grid NeRF pretraining run (seconds on a synthetic scene).
pub const NERF_TINY: &[&str] = &[
    "--steps",
    "40",
    "--target-samples",
    "8192",
    "--log2-table",
    "12",
    "--max-resolution",
    "64",
    "--occupancy-resolution",
    "16",
    "--eval-every",
    "20",
    "--eval-views",
    "1",
    "--checkpoint-every",
    "20",
    "--quiet",
    "--backend",
    "flex",
];

/// A small grid NeRF: `NERF_TINY`'s network at twice the resolution, 600 steps.
pub const NERF_SMALL: &[&str] = &[
    "--steps",
    "600",
    "--target-samples",
    "16384",
    "--log2-table",
    "14",
    "--max-resolution",
    "128",
    "--occupancy-resolution",
    "32",
    "--eval-every",
    "600",
    "--eval-views",
    "1",
    "--checkpoint-every",
    "600",
    "--quiet",
    "--backend",
    "flex",
];

/// Writes a `data synth` scene of `format` (`size` pixels, `views` views) to `dir/scene`.
pub fn synth_scene(dir: &Path, format: &str, size: u32, views: u32) -> std::path::PathBuf {
    let scene = dir.join("scene");
    let (size, views) = (size.to_string(), views.to_string());
    ok(cli(&[
        "data",
        "synth",
        "--format",
        format,
        "--out",
        s(&scene),
        "--size",
        &size,
        "--views",
        &views,
    ]));
    scene
}

/// Writes a 32×32 painting (red across, green down, blue 200) to `path` and returns it.
pub fn gradient_painting(path: &Path) -> std::path::PathBuf {
    image::RgbImage::from_fn(32, 32, |x, y| {
        image::Rgb([(x * 8) as u8, (y * 8) as u8, 200])
    })
    .save(path)
    .unwrap();
    path.to_path_buf()
}

/// Two stylizing steps of `run` with the generated painting (written into `dir`), into
/// `dir/stylized`, which it returns.
pub fn stylize_nerf_briefly(run: &Path, dir: &Path) -> std::path::PathBuf {
    let style = gradient_painting(&dir.join("style.png"));
    let out = dir.join("stylized");
    ok(stylize_nerf(
        run,
        &[&style],
        &out,
        &["--steps", "2", "--patch", "12", "--style-size", "32"],
    ));
    out
}

/// A short stylization of the NeRF run `run` on flex into `out` with `styles` in order
/// (full-resolution patches, no evaluation, quiet); `extra` gives the steps, patch size and
/// anything else the test needs.
pub fn stylize_nerf(run: &Path, styles: &[&Path], out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["train", "nerf", "--from", s(run), "--out", s(out)];
    for style in styles {
        args.extend(["--style", s(style)]);
    }
    args.extend([
        "--stride",
        "1",
        "--eval-every",
        "0",
        "--quiet",
        "--backend",
        "flex",
    ]);
    args.extend_from_slice(extra);
    cli(&args)
}
