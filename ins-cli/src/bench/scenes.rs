//! Inputs the benchmarks make for themselves: a synthetic scene in a temporary folder, a VGG-16
//! of random weights and a random painting, so no download or dataset is needed.

use anyhow::{Context, Result};
use burn::prelude::*;
use burn::tensor::Distribution;
use ins_conv::Precision;
use ins_core::imaging::RgbImage;
use ins_core::loss::PerceptualLoss;
use ins_scene::data::synthetic::{SynthOptions, write_blender};
use vgg_import::{Preprocess, Vgg, Vgg16Features};

/// A synthetic NeRF-synthetic (Blender) scene of `views` views at `size`², written into a
/// temporary folder that lives as long as the returned guard.
pub fn blender_scene(
    size: u32,
    views: usize,
) -> Result<(tempfile::TempDir, ins_models::nerf::run::NerfScene)> {
    let dir = tempfile::tempdir().context("a temporary folder for the synthetic scene")?;
    write_blender(dir.path(), &SynthOptions { size, views })?;
    let (scene, format, _) = ins_models::run::scene::load_scene(dir.path(), 1, None)?;
    Ok((dir, ins_models::nerf::run::NerfScene { scene, format }))
}

/// VGG-16 of random (He-initialised) weights at `precision`, Caffe's input convention.
pub fn random_vgg(device: &Device, precision: Precision) -> Vgg {
    Vgg {
        net: Vgg16Features::random(device).with_precision(precision),
        preprocess: Preprocess::Caffe,
    }
}

/// A painting of uniform noise, `side`².
pub fn random_painting(side: usize, device: &Device) -> Result<RgbImage> {
    let t = Tensor::<3>::random([side, side, 3], Distribution::Uniform(0.0, 1.0), device);
    RgbImage::from_hwc(t.inner())
}

/// The perceptual loss of one random painting at 256², through a random VGG.
pub fn random_perceptual(device: &Device, precision: Precision) -> Result<PerceptualLoss> {
    let painting = random_painting(256, device)?;
    Ok(PerceptualLoss::new(
        random_vgg(device, precision),
        &[painting],
        256,
        ins_core::loss::StyleLoss::Gram,
        device,
    ))
}

/// A pretrained NeRF run held in memory (no checkpoint on disk), to stylize from: its folder
/// `dir/base`, the config, the scene, the model and its occupancy grid (grid variant).
pub fn base_run(
    dir: &std::path::Path,
    config: &ins_models::nerf::NerfRunConfig,
    data: ins_models::nerf::run::NerfScene,
    model: ins_models::nerf::NerfModel,
    grid: Option<ins_core::render::occupancy::OccupancyGrid>,
) -> ins_models::run::Run<ins_models::nerf::Nerf> {
    ins_models::run::Run {
        dir: dir.join("base"),
        config: config.clone(),
        base: None,
        data,
        model,
        extra: ins_models::nerf::state_io::NerfState {
            grid,
            ..Default::default()
        },
    }
}
