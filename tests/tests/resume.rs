//! Checkpoints and resume, alone in their own test binary: flex reduces in parallel, and
//! when other tests share the thread pool the summation order (so the last bits of every sum)
//! varies, which Adam then amplifies. Alone, a resumed run must match an uninterrupted one.

use burn::prelude::*;
use ins_models::demo::{demo_content, demo_style};
use ins_models::siren::SirenRun;
use ins_tests::{quiet_options, real_vgg, save_image, small_config, train_siren as train};

#[test]
fn checkpoint_reload_renders_identically_and_resume_continues_the_same_run() {
    let device = Device::flex();
    let vgg = real_vgg(&device);
    let dir = tempfile::tempdir().unwrap();
    let content = save_image(dir.path(), "c.png", &demo_content(24));
    let style = save_image(dir.path(), "s.png", &demo_style(32));
    let mut cfg = small_config(content, vec![style], 24);
    cfg.hidden = 64;
    cfg.fit_steps = 20;
    cfg.stylize_steps = 10;
    cfg.style.patch = 24;

    // Uninterrupted.
    let a_dir = dir.path().join("a");
    let a = train(&cfg, vgg.clone(), &device, quiet_options(&a_dir)).unwrap();
    assert!(a.finished);
    let a_img =
        ins_models::image_task::render_image(&a.model.valid(), 24, 24, &[1.0], &device).unwrap();
    let reloaded = SirenRun::load(&a_dir, &device).unwrap();
    let r_img = reloaded.render(24, 24, &[1.0], &device).unwrap();
    assert_eq!(
        a_img.data, r_img.data,
        "reloaded checkpoint renders differently"
    );

    // Interrupted after 15 steps (inside fitting, past a checkpoint), then resumed.
    let b_dir = dir.path().join("b");
    let mut o = quiet_options(&b_dir);
    o.checkpoint_every = 5;
    o.stop_after = Some(15);
    let b1 = train(&cfg, vgg.clone(), &device, o.clone()).unwrap();
    assert!(!b1.finished);
    assert_eq!(b1.steps, 15);
    o.stop_after = None;
    o.resume = true;
    let b2 = train(&cfg, vgg.clone(), &device, o).unwrap();
    assert!(b2.finished);
    assert_eq!(b2.steps, 30);
    let b_img = SirenRun::load(&b_dir, &device)
        .unwrap()
        .render(24, 24, &[1.0], &device)
        .unwrap();
    let diff = a_img
        .data
        .iter()
        .zip(&b_img.data)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(
        diff < 1e-5,
        "resumed run differs from the uninterrupted one by {diff}"
    );

    // The metrics log of the resumed run covers every logged step once.
    let log = std::fs::read_to_string(b_dir.join("metrics.jsonl")).unwrap();
    let steps: Vec<u64> = log
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["step"]
                .as_u64()
                .unwrap()
        })
        .collect();
    let mut sorted = steps.clone();
    sorted.dedup();
    assert_eq!(
        steps, sorted,
        "duplicated or unordered steps in metrics.jsonl"
    );

    // A run folder is not silently overwritten.
    let again = train(&cfg, vgg, &device, quiet_options(&a_dir));
    assert!(again.is_err());
}
