//! SIREN + INS end to end: fitting, stylization, multi-style conditioning and interpolation,
//! checkpoints and resume. Small images and few steps; the real VGG-16 supervises.

use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{self, StyleTarget};
use ins_models::demo::{demo_content, demo_style};
use ins_models::siren::SirenRun;
use ins_tests::{quiet_options, real_vgg, save_image, small_config, train_siren as train};
use vgg_import::Vgg;

/// Red and white diagonal stripes: a style nothing like the demo painting.
fn stripes(size: usize) -> RgbImage {
    let mut data = Vec::with_capacity(size * size * 3);
    for v in 0..size {
        for u in 0..size {
            let on = ((u + v) / 4) % 2 == 0;
            data.extend(if on {
                [0.9, 0.1, 0.1]
            } else {
                [1.0, 0.95, 0.9]
            });
        }
    }
    RgbImage {
        width: size,
        height: size,
        data,
    }
}

/// Style distance of an image to a style image (the loss the trainer minimises).
fn style_distance(vgg: &Vgg, img: &RgbImage, style: &RgbImage, device: &Device) -> f64 {
    let t = StyleTarget::from_image(vgg, style.to_tensor(device)).grams;
    loss::style_distance(vgg, img.to_tensor(device), &t)
}

fn content_distance(vgg: &Vgg, img: &RgbImage, content: &RgbImage, device: &Device) -> f64 {
    loss::content_distance(vgg, img.to_tensor(device), content.to_tensor(device))
}

#[test]
fn siren_fits_an_image() {
    let device = Device::flex();
    let dir = tempfile::tempdir().unwrap();
    let content = save_image(dir.path(), "c.png", &demo_content(32));
    let style = save_image(dir.path(), "s.png", &demo_style(32));
    let mut cfg = small_config(content, vec![style], 32);
    cfg.fit_steps = 300;
    cfg.stylize_steps = 0;
    let out = train(
        &cfg,
        real_vgg(&device),
        &device,
        quiet_options(&dir.path().join("run")),
    )
    .unwrap();
    let psnr = out.last["psnr"];
    assert!(psnr > 30.0, "PSNR after fitting: {psnr:.2} dB");
    assert!(dir.path().join("run/loss_curve.png").exists());
    assert!(dir.path().join("run/metrics.jsonl").exists());
    assert!(dir.path().join("run/stylized.png").exists());
}

#[test]
fn stylization_moves_towards_the_style_and_keeps_the_content() {
    let device = Device::flex();
    let vgg = real_vgg(&device);
    let dir = tempfile::tempdir().unwrap();
    let content_img = demo_content(48);
    let style_img = demo_style(64);
    let content = save_image(dir.path(), "c.png", &content_img);
    let style = save_image(dir.path(), "s.png", &style_img);
    let cfg = small_config(content, vec![style], 48);
    let run_dir = dir.path().join("run");
    train(&cfg, vgg.clone(), &device, quiet_options(&run_dir)).unwrap();
    let result = RgbImage::load(&run_dir.join("stylized.png")).unwrap();
    let before = style_distance(&vgg, &content_img, &style_img, &device);
    let after = style_distance(&vgg, &result, &style_img, &device);
    assert!(after < before / 5.0, "style distance {before} → {after}");
    // Still closer in content to the photo than the painting itself is.
    let kept = content_distance(&vgg, &result, &content_img, &device);
    let painting = content_distance(&vgg, &style_img.resized(48, 48), &content_img, &device);
    assert!(
        kept < painting,
        "content distance {kept} vs the painting's {painting}"
    );
}

#[test]
fn two_styles_condition_the_render_and_interpolate_monotonically() {
    let device = Device::flex();
    let vgg = real_vgg(&device);
    let dir = tempfile::tempdir().unwrap();
    let s1 = demo_style(64);
    let s2 = stripes(64);
    let content = save_image(dir.path(), "c.png", &demo_content(48));
    let p1 = save_image(dir.path(), "s1.png", &s1);
    let p2 = save_image(dir.path(), "s2.png", &s2);
    let mut cfg = small_config(content, vec![p1, p2], 48);
    cfg.stylize_steps = 150;
    let run_dir = dir.path().join("run");
    train(&cfg, vgg.clone(), &device, quiet_options(&run_dir)).unwrap();
    let run = SirenRun::load(&run_dir, &device).unwrap();
    let r10 = run.render(48, 48, &[1.0, 0.0], &device).unwrap();
    let r01 = run.render(48, 48, &[0.0, 1.0], &device).unwrap();
    let d = |img: &RgbImage, s: &RgbImage| style_distance(&vgg, img, s, &device);
    assert!(
        d(&r10, &s1) < d(&r10, &s2),
        "[1,0] render is not nearer style 1"
    );
    assert!(
        d(&r01, &s2) < d(&r01, &s1),
        "[0,1] render is not nearer style 2"
    );
    // Along the interpolation the render moves away from style 1 towards style 2.
    let steps: Vec<f64> = (0..5)
        .map(|i| {
            let t = i as f32 / 4.0;
            let img = run.render(48, 48, &[1.0 - t, t], &device).unwrap();
            d(&img, &s2) / d(&img, &s1)
        })
        .collect();
    for w in steps.windows(2) {
        assert!(
            w[1] < w[0],
            "distance ratio to style 2 / style 1 is not decreasing: {steps:?}"
        );
    }
}
