//! `ins-cli train idr`, `render idr` and `eval idr`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use clap::{ArgMatches, Args};
use ins_core::imaging::RgbImage;
use ins_models::idr::eval::{evaluate_views, mean_scores, render_camera};
use ins_models::idr::{Idr, IdrRun, IdrRunConfig};
use ins_models::run::RunKind;
use ins_scene::camera::Camera;
use ins_scene::paths::{PathKind, path_for_scene};

use crate::common::{DeviceArgs, RunArgs, TrainCommand, VggArgs, merged_config, parse_size};
use crate::counter::Counter;
use ins_models::video::{FrameOutput, write_frames};

#[derive(Args, Debug)]
pub struct TrainIdr {
    /// Run folder (metrics, loss curve, val pictures, config, checkpoints).
    #[arg(long, default_value = "runs/idr")]
    out: PathBuf,
    #[command(flatten)]
    config: IdrRunConfig,
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    device: DeviceArgs,
    #[command(flatten)]
    vgg: VggArgs,
}

pub fn train(a: TrainIdr, matches: &ArgMatches) -> Result<()> {
    let cfg = merged_config::<Idr>(a.config, matches, a.run.config.as_deref())?;
    let what = match cfg.kind()? {
        RunKind::Pretrain => format!("reconstructing a surface ({} SDF)", cfg.sdf),
        RunKind::Stylize => format!(
            "stylizing a surface with {} style(s)",
            cfg.style.styles.len()
        ),
    };
    let next = format!(
        "see {o}/val/; render with `ins-cli render idr --run {o}`, mesh with `ins-cli export mesh --run {o}`",
        o = a.out.display()
    );
    let cmd = TrainCommand {
        out: &a.out,
        run: &a.run,
        device: &a.device,
        vgg: &a.vgg,
    };
    cmd.train::<Idr>(&cfg, cfg.schedule.checkpoint_every, &what, &next)?;
    Ok(())
}

#[derive(Args, Debug)]
pub struct RenderIdr {
    /// Run folder written by `train idr`.
    #[arg(long)]
    run: PathBuf,
    /// One view by index (default: the scene's path, see --path and --frames).
    #[arg(long)]
    view: Option<usize>,
    /// A camera path: arc (over the side the capture saw; the default where the cameras leave
    /// a side unseen, as DTU's do), turntable or spiral.
    #[arg(long, conflicts_with = "view")]
    path: Option<PathKind>,
    /// One view at a viewer pose AZ,EL[,DIST[,PANX,PANY]] (as `ins-cli view` shows it, held
    /// to the range the viewer allows: the photos' elevations and a partial capture's arc, 10°
    /// beyond).
    #[arg(long, conflicts_with_all = ["view", "path"])]
    orbit: Option<String>,
    /// Frames of the path.
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Style weights, comma-separated (stylized runs).
    #[arg(long, value_delimiter = ',')]
    mix: Option<Vec<f32>>,
    /// Render shaded normals instead of colour.
    #[arg(long)]
    normals: bool,
    /// Output size WxH (default: the run's training resolution).
    #[arg(long)]
    size: Option<String>,
    /// Output: a .png (one view), a .gif or .mp4 (a path), or a folder (frames).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn render(a: RenderIdr) -> Result<()> {
    let device = a.device.device()?;
    let run = IdrRun::load(&a.run, &device)?;
    let code = run.code(a.mix.as_deref(), &device)?;
    let size = a.size.as_deref().map(parse_size).transpose()?;
    let model = run.model.valid();
    let opts = run.config.view_options();
    let shoot = |camera: &Camera| -> Result<RgbImage> {
        let r = render_camera(
            &model,
            &run.scene(),
            &crate::view_size::resized(camera, size),
            code.clone(),
            &opts,
            &device,
        )?;
        Ok(if a.normals {
            r.normal_image()
        } else {
            r.image()
        })
    };
    if let Some(orbit) = &a.orbit {
        let cam = crate::view_size::orbit_camera(&run.scene(), orbit, size)?;
        shoot(&cam)?.save(&a.out)?;
        println!("{}", a.out.display());
        return Ok(());
    }
    if let Some(view) = a.view {
        let v = run.scene().views.get(view).with_context(|| {
            format!(
                "--view {view}: the scene has {} views",
                run.scene().views.len()
            )
        })?;
        shoot(&v.camera)?.save(&a.out)?;
        println!("{}", a.out.display());
        return Ok(());
    }
    let cameras =
        path_for_scene(&run.scene(), a.path, a.frames).context("the scene has no cameras")?;
    let output = FrameOutput::for_path(&a.out)?;
    let mut frames = Vec::new();
    let mut counter = Counter::new("rendered", cameras.len());
    for (i, c) in cameras.iter().enumerate() {
        frames.push(shoot(c)?);
        counter.done(i + 1);
    }
    let names: Vec<String> = (0..frames.len())
        .map(|i| format!("frame_{i:04}.png"))
        .collect();
    for w in write_frames(&frames, &names, &output, 12)? {
        println!("{}", w.display());
    }
    Ok(())
}

#[derive(Args, Debug)]
pub struct EvalIdr {
    /// Run folder written by `train idr`.
    #[arg(long)]
    run: PathBuf,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn eval(a: EvalIdr) -> Result<()> {
    let device = a.device.device()?;
    let run = IdrRun::load(&a.run, &device)?;
    let views = run.scene().split(ins_scene::data::Split::Val).to_vec();
    if views.is_empty() {
        bail!(
            "{}: the run holds no views out; train with --holdout K to evaluate",
            a.run.display()
        );
    }
    let code = run.code(None, &device)?;
    let evals = evaluate_views(
        &run.model.valid(),
        run.scene(),
        &views,
        code,
        &run.config.view_options(),
        &device,
    )?;
    for e in &evals {
        println!(
            "{}",
            serde_json::json!({"view": e.view, "iou": (e.iou * 10000.0).round() / 10000.0, "psnr_mask": (e.psnr_mask * 1000.0).round() / 1000.0, "psnr": (e.psnr * 1000.0).round() / 1000.0})
        );
    }
    let mean = mean_scores(&evals);
    println!(
        "{}",
        serde_json::json!({
            "mean": true,
            "views": evals.len(),
            "iou": (mean["iou"] * 10000.0).round() / 10000.0,
            "psnr_mask": (mean["psnr_mask"] * 1000.0).round() / 1000.0,
            "psnr": (mean["psnr"] * 1000.0).round() / 1000.0,
            // Whether training saw the masks (without them, the scores are against masks it
            // never used).
            "masks_used": run.masked(),
        })
    );
    Ok(())
}
