//! `ins-cli train nerf`, `render nerf` and `eval nerf`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use clap::{ArgMatches, Args};
use ins_core::imaging::RgbImage;
use ins_models::nerf::eval::{ViewRender, depth_agreement, evaluate_views, render_camera};
use ins_models::nerf::{Nerf, NerfRun, NerfRunConfig};
use ins_models::run::RunKind;
use ins_scene::camera::Camera;
use ins_scene::data::Split;
use ins_scene::paths::{PathKind, path_for_scene};

use crate::common::{DeviceArgs, RunArgs, TrainCommand, VggArgs, merged_config, parse_size};
use crate::counter::Counter;
use ins_models::video::{FrameOutput, write_frames};

#[derive(Args, Debug)]
pub struct TrainNerf {
    /// Run folder (metrics, loss curve, val pictures, config, checkpoints).
    #[arg(long, default_value = "runs/nerf")]
    out: PathBuf,
    #[command(flatten)]
    config: NerfRunConfig,
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    device: DeviceArgs,
    #[command(flatten)]
    vgg: VggArgs,
}

pub fn train(a: TrainNerf, matches: &ArgMatches) -> Result<()> {
    let cfg = merged_config::<Nerf>(a.config, matches, a.run.config.as_deref())?;
    let what = match cfg.kind()? {
        RunKind::Pretrain => format!(
            "pretraining a NeRF ({} content module) on {}",
            cfg.cim,
            cfg.source
                .scene
                .as_ref()
                .map_or(String::new(), |p| p.display().to_string())
        ),
        RunKind::Stylize => format!(
            "stylizing {} with {} style{}",
            cfg.source
                .from
                .as_ref()
                .map_or(String::new(), |p| p.display().to_string()),
            cfg.style.styles.len(),
            if cfg.style.styles.len() == 1 { "" } else { "s" }
        ),
    };
    let next = format!(
        "see {o}/val/ and loss_curve.png; render with `ins-cli render nerf --run {o}`",
        o = a.out.display()
    );
    let cmd = TrainCommand {
        out: &a.out,
        run: &a.run,
        device: &a.device,
        vgg: &a.vgg,
    };
    cmd.train::<Nerf>(&cfg, cfg.schedule.checkpoint_every, &what, &next)?;
    Ok(())
}

/// Which cameras to render.
#[derive(Args, Debug)]
#[group(required = false, multiple = false)]
pub struct Cameras {
    /// Every view of a split (val or test); --out is a folder.
    #[arg(long)]
    split: Option<Split>,
    /// One view by index.
    #[arg(long)]
    view: Option<usize>,
    /// A camera path: spiral (forward-facing scenes), turntable (scenes seen all around) or
    /// arc (over the side a partial capture saw). Default: the scene's.
    #[arg(long)]
    path: Option<PathKind>,
    /// One view at a viewer pose AZ,EL[,DIST[,PANX,PANY]] (as `ins-cli view` shows it, held
    /// to the range the viewer allows: a forward-facing scene's spiral; elsewhere the photos'
    /// elevations and a partial capture's arc, 10° beyond).
    #[arg(long)]
    orbit: Option<String>,
}

#[derive(Args, Debug)]
pub struct RenderNerf {
    /// Run folder written by `train nerf`.
    #[arg(long)]
    run: PathBuf,
    #[command(flatten)]
    cameras: Cameras,
    /// Frames of a --path.
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Style weights, comma-separated (stylized runs; default: the first style).
    #[arg(long, value_delimiter = ',')]
    mix: Option<Vec<f32>>,
    /// Render the depth (colour-mapped) instead of the colour.
    #[arg(long)]
    depth: bool,
    /// Output size WxH (default: the run's training resolution).
    #[arg(long)]
    size: Option<String>,
    /// Output: a .png (one view), a .gif or .mp4 (a path), or a folder (frames).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    device: DeviceArgs,
}

fn picture(r: &ViewRender, depth: bool) -> RgbImage {
    if depth { r.depth_picture() } else { r.image() }
}

pub fn render(a: RenderNerf) -> Result<()> {
    let device = a.device.device()?;
    let run = NerfRun::load(&a.run, &device)?;
    let code = run.code(a.mix.as_deref(), &device)?;
    let size = a.size.as_deref().map(parse_size).transpose()?;
    let model = run.model.valid();
    let scene = &run.scene();
    let shoot = |camera: &Camera| -> Result<RgbImage> {
        let cam = crate::view_size::resized(camera, size);
        let r = render_camera(
            &model,
            scene,
            &cam,
            run.sampling(),
            code.clone(),
            run.background(),
            &device,
        )?;
        Ok(picture(&r, a.depth))
    };
    let c = &a.cameras;
    if let Some(orbit) = &c.orbit {
        let cam = crate::view_size::orbit_camera(scene, orbit, size)?;
        shoot(&cam)?.save(&a.out)?;
        println!("{}", a.out.display());
        return Ok(());
    }
    if let Some(view) = c.view {
        let v = scene
            .views
            .get(view)
            .with_context(|| format!("--view {view}: the scene has {} views", scene.views.len()))?;
        let img = shoot(&v.camera)?;
        img.save(&a.out)?;
        println!("{}", a.out.display());
        return Ok(());
    }
    let (cameras, names): (Vec<Camera>, Vec<String>) = if let Some(split) = c.split {
        let views = scene.split(split);
        if views.is_empty() {
            bail!("{}: split {split} has no views", scene.root.display());
        }
        views
            .iter()
            .map(|&i| (scene.views[i].camera.clone(), format!("{split}_{i:03}.png")))
            .unzip()
    } else {
        let cams = path_for_scene(&run.scene(), c.path, a.frames)
            .context("the scene has no cameras to build a path from")?;
        let names = (0..cams.len())
            .map(|i| format!("frame_{i:04}.png"))
            .collect();
        (cams, names)
    };
    let output = FrameOutput::for_path(&a.out)?;
    let mut frames = Vec::with_capacity(cameras.len());
    let mut counter = Counter::new("rendered", cameras.len());
    for (i, cam) in cameras.iter().enumerate() {
        frames.push(shoot(cam)?);
        counter.done(i + 1);
    }
    let written = write_frames(&frames, &names, &output, 12)?;
    for w in written {
        println!("{}", w.display());
    }
    Ok(())
}

#[derive(Args, Debug)]
pub struct EvalNerf {
    /// Run folder written by `train nerf`.
    #[arg(long)]
    run: PathBuf,
    /// Split to evaluate (default: val, or test where the scene has no val split).
    #[arg(long)]
    split: Option<Split>,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn eval(a: EvalNerf) -> Result<()> {
    let device = a.device.device()?;
    let run = NerfRun::load(&a.run, &device)?;
    let scene = &run.scene();
    let views: Vec<usize> = match a.split {
        Some(s) => scene.split(s).to_vec(),
        None => ins_models::run::scene::heldout_views(scene),
    };
    if views.is_empty() {
        bail!(
            "{}: no held-out views to evaluate (choose --split)",
            scene.root.display()
        );
    }
    let model = run.model.valid();
    let stylized = run.base.is_some();
    let code = run.code(None, &device)?;
    let evals = evaluate_views(
        &model,
        scene,
        &views,
        run.sampling(),
        code,
        run.background(),
        &device,
    )?;
    let teacher = match &run.config.source.from {
        Some(from) if stylized => Some(NerfRun::load(from, &device)?),
        _ => None,
    };
    let (mut sum_psnr, mut sum_ssim, mut depth_errors, mut agreements) =
        (0.0, 0.0, Vec::new(), Vec::new());
    for e in &evals {
        let mut line = serde_json::json!({
            "view": e.view,
            "psnr": (e.psnr * 1000.0).round() / 1000.0,
            "ssim": (e.ssim * 10000.0).round() / 10000.0,
        });
        if let Some(t) = &teacher {
            let cam = &scene.views[e.view].camera;
            let tr = render_camera(
                &t.model.valid(),
                &t.scene(),
                cam,
                t.sampling(),
                None,
                t.background(),
                &device,
            )?;
            let d = depth_agreement(&e.render, &tr);
            line["depth_rel_error_median"] = d.median_rel_error.into();
            line["opacity_agreement"] = d.agreement.into();
            line["opaque_pixels"] = d.both.into();
            depth_errors.push(d.median_rel_error);
            agreements.push(d.agreement);
        }
        println!("{line}");
        sum_psnr += e.psnr;
        sum_ssim += e.ssim;
    }
    let n = evals.len() as f64;
    let mut mean = serde_json::json!({
        "mean": true,
        "views": evals.len(),
        "psnr": (sum_psnr / n * 1000.0).round() / 1000.0,
        "ssim": (sum_ssim / n * 10000.0).round() / 10000.0,
    });
    if !depth_errors.is_empty() {
        mean["depth_rel_error_median"] = (depth_errors.iter().sum::<f64>() / n).into();
        mean["opacity_agreement"] = (agreements.iter().sum::<f64>() / n).into();
        mean["note"] =
            "PSNR/SSIM of a stylized run compare the stylized render with the photos".into();
    }
    println!("{mean}");
    if !stylized && ins_models::nerf::view_audit::audits_views(scene) {
        note_misposed_views(scene, &evals);
    }
    Ok(())
}

/// Names the held-out photos of a capture that fit far below the others, as the training
/// audit does for training photos: a photo posed wrongly by structure from motion scores the
/// poses, not the field. The mean above keeps them; the note gives the mean without them.
fn note_misposed_views(scene: &ins_scene::data::Scene, evals: &[ins_models::nerf::eval::ViewEval]) {
    use ins_models::nerf::view_audit::{ViewFit, median_psnr, outliers, photo_name};
    let fits: Vec<ViewFit> = evals
        .iter()
        .map(|e| ViewFit {
            view: e.view,
            psnr: e.psnr,
        })
        .collect();
    let out = outliers(&fits);
    if out.is_empty() {
        return;
    }
    let names: Vec<String> = out
        .iter()
        .map(|f| {
            let name = photo_name(scene, f.view);
            format!("view {} ({name}, {:.1} dB)", f.view, f.psnr)
        })
        .collect();
    let rest: Vec<f64> = fits
        .iter()
        .filter(|f| !out.iter().any(|o| o.view == f.view))
        .map(|f| f.psnr)
        .collect();
    eprintln!(
        "note: {} fit{} far below the other held-out photos (median {:.1} dB): likely posed \
         wrongly; the mean without {}: {:.2} dB",
        names.join(", "),
        if out.len() == 1 { "s" } else { "" },
        median_psnr(&fits),
        if out.len() == 1 { "it" } else { "them" },
        rest.iter().sum::<f64>() / rest.len().max(1) as f64
    );
}
