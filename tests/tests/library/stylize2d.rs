//! Classic 2D style transfer (the per-view baseline): it must move an image far towards the
//! painting's style while keeping its content, with the real VGG-16.

use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{
    LossWeights, StyleLoss, StyleTarget, StyleTargets, content_distance, style_distance,
};
use ins_models::demo::{demo_content, demo_style};
use ins_models::stylize2d::{Stylize2dSettings, stylize};
use ins_tests::{quiet_options, real_vgg};
use vgg_import::Vgg;

/// 60 steps against a 64-px painting, with the loss's default weights.
fn settings(vgg: &Vgg, style_loss: StyleLoss, match_radius: Option<f32>) -> Stylize2dSettings {
    Stylize2dSettings {
        steps: 60,
        lr: 0.02,
        weights: LossWeights::default_for(vgg.preprocess, style_loss),
        style_size: 64,
        style_loss,
        match_radius,
    }
}

#[test]
fn gatys_lowers_the_gram_distance_five_fold_and_keeps_the_content() {
    let device = Device::flex();
    let vgg = real_vgg(&device);
    let dir = tempfile::tempdir().unwrap();
    let content = demo_content(48);
    let style = demo_style(64);
    let (result, outcome) = stylize(
        &content,
        &style,
        vgg.clone(),
        &settings(&vgg, StyleLoss::Gram, None),
        quiet_options(dir.path()),
        &device,
    )
    .unwrap();
    assert_eq!(outcome.steps, 60);
    assert_eq!((result.width, result.height), (48, 48));
    assert!(result.data.iter().all(|v| (0.0..=1.0).contains(v)));
    let targets = StyleTarget::from_image(&vgg, style.to_tensor(&device)).grams;
    let before = style_distance(&vgg, content.to_tensor(&device), &targets);
    let after = style_distance(&vgg, result.to_tensor(&device), &targets);
    eprintln!("Gram distance {before} → {after}");
    assert!(after < before / 5.0, "Gram distance {before} → {after}");
    let kept = content_distance(&vgg, result.to_tensor(&device), content.to_tensor(&device));
    let painting = content_distance(
        &vgg,
        style.resized(48, 48).to_tensor(&device),
        content.to_tensor(&device),
    );
    eprintln!("content distance {kept} (painting: {painting})");
    assert!(
        kept < painting / 2.0,
        "content distance {kept} vs the painting's {painting}"
    );
    // The trainer's record of the run is there: metrics and a loss curve.
    assert!(dir.path().join("metrics.jsonl").exists());
    assert!(dir.path().join("loss_curve.png").exists());
}

#[test]
fn nnfm_guided_by_the_photo_keeps_more_of_it_than_unguided_and_still_moves_towards_the_painting() {
    let device = Device::flex();
    let vgg = real_vgg(&device);
    let content = demo_content(48);
    let style = demo_style(64);
    let run = |match_radius: Option<f32>| {
        let dir = tempfile::tempdir().unwrap();
        let (result, _) = stylize(
            &content,
            &style,
            vgg.clone(),
            &settings(&vgg, StyleLoss::Nnfm, match_radius),
            quiet_options(dir.path()),
            &device,
        )
        .unwrap();
        result
    };
    let (unguided, guided) = (run(None), run(Some(0.05)));
    let kept =
        |img: &RgbImage| content_distance(&vgg, img.to_tensor(&device), content.to_tensor(&device));
    // Plain NNFM's distance to the painting, the same yardstick for all three images.
    let targets = StyleTargets::from_images(
        StyleLoss::Nnfm,
        &vgg,
        &[style.fit_within(64).to_tensor(&device)],
    );
    let nnfm = |img: &RgbImage| {
        targets
            .loss(&vgg.features(img.to_tensor(&device)), None)
            .into_scalar::<f32>()
    };
    eprintln!(
        "content distance: unguided {} guided {}; NNFM: photo {} unguided {} guided {}",
        kept(&unguided),
        kept(&guided),
        nnfm(&content),
        nnfm(&unguided),
        nnfm(&guided)
    );
    assert!(
        kept(&guided) < kept(&unguided),
        "guided {} vs unguided {}",
        kept(&guided),
        kept(&unguided)
    );
    assert!(
        nnfm(&guided) < nnfm(&content),
        "the guided run did not move"
    );
}
