//! `ins-cli stylize2d` as a user meets it: one image, a folder of frames (kept when the run is
//! repeated), and bad input.

use ins_core::imaging::RgbImage;
use ins_models::demo::{demo_content, demo_style};

use crate::common::*;

#[test]
fn stylizes_an_image_and_a_folder_of_frames_and_refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let style = d.join("style.png");
    demo_style(48).save(&style).unwrap();
    let frames = d.join("frames");
    std::fs::create_dir(&frames).unwrap();
    for i in 0..2 {
        demo_content(32 + 8 * i)
            .save(&frames.join(format!("f{i}.png")))
            .unwrap();
    }
    let quick = [
        "--steps",
        "10",
        "--backend",
        "flex",
        "--quiet",
        "--style-size",
        "48",
    ];

    // One image: the PNG at the content's size, metrics beside it.
    let out = d.join("one.png");
    let f0 = frames.join("f0.png");
    let mut args = vec!["stylize2d", "--content", s(&f0)];
    args.extend(["--style", s(&style), "--out", s(&out)]);
    args.extend(quick);
    let o = ok(cli(&args));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["steps"], 10);
    let img = RgbImage::load(&out).unwrap();
    assert_eq!((img.width, img.height), (32, 32));
    assert!(d.join("one.png.run/metrics.jsonl").exists());

    // A folder: one output per frame, each at its own size; a repeated run keeps them.
    let styled = d.join("styled");
    let mut args = vec!["stylize2d", "--frames", s(&frames), "--style", s(&style)];
    args.extend(["--out", s(&styled)]);
    args.extend(quick);
    ok(cli(&args));
    for (i, side) in [(0, 32), (1, 40)] {
        let img = RgbImage::load(&styled.join(format!("f{i}.png"))).unwrap();
        assert_eq!((img.width, img.height), (side, side));
    }
    let again = ok(cli(&args));
    assert_eq!(stderr(&again).matches("exists, kept").count(), 2);

    // Bad input: a missing painting, an empty folder, both sources at once.
    let missing = d.join("nope.png");
    let mut args = vec!["stylize2d", "--content", s(&out), "--style", s(&missing)];
    let x = d.join("x.png");
    args.extend(["--out", s(&x)]);
    args.extend(quick);
    assert_clean_failure(&cli(&args), "nope.png");
    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let mut args = vec!["stylize2d", "--frames", s(&empty), "--style", s(&style)];
    let y = d.join("y");
    args.extend(["--out", s(&y)]);
    args.extend(quick);
    assert_clean_failure(&cli(&args), "no PNG or JPEG images");
    let mut args = vec!["stylize2d", "--frames", s(&frames), "--content", s(&out)];
    let z = d.join("z");
    args.extend(["--style", s(&style), "--out", s(&z)]);
    assert_clean_failure(&cli(&args), "cannot be used with");
    assert!(!x.exists() && !z.exists());
}
