//! `ins-cli train idr`, `render idr`, `eval idr` and `export mesh`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use clap::{ArgMatches, Args};
use ins_core::imaging::RgbImage;
use ins_core::render::sphere_tracing::TraceOptions;
use ins_models::config::merge_with_file;
use ins_models::idr::eval::{evaluate_views, render_camera};
use ins_models::idr::mesh::extract_mesh;
use ins_models::idr::{Idr, IdrRun, IdrRunConfig};
use ins_models::run::RunKind;
use ins_scene::camera::Camera;
use ins_scene::paths::turntable_for_scene;

use crate::common::{DeviceArgs, RunArgs, TrainCommand, parse_size};
use crate::vgg_cmd::VggArgs;
use crate::video::{FrameOutput, write_frames};

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
    let cfg = merge_with_file(a.config, matches, a.run.config.as_deref())?;
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
    /// One view by index (default: a turntable, see --frames).
    #[arg(long)]
    view: Option<usize>,
    /// A camera path: turntable.
    #[arg(long, conflicts_with = "view")]
    path: Option<String>,
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
    let device = a.device.device();
    let run = IdrRun::load(&a.run, &device)?;
    let code = run.code(a.mix.as_deref(), &device)?;
    let size = a.size.as_deref().map(parse_size).transpose()?;
    let model = run.model.valid();
    let trace = TraceOptions::default();
    let shoot = |camera: &Camera| -> Result<RgbImage> {
        let r = render_camera(
            &model,
            &run.scene(),
            &crate::view_size::resized(camera, size),
            code.clone(),
            &trace,
            &device,
        )?;
        Ok(if a.normals {
            r.normal_image()
        } else {
            r.image()
        })
    };
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
    match a.path.as_deref().unwrap_or("turntable") {
        "turntable" => {}
        other => bail!("unknown --path {other:?} (surfaces render on a turntable)"),
    }
    let cameras =
        turntable_for_scene(&run.scene(), a.frames).context("the scene has no cameras")?;
    let output = FrameOutput::for_path(&a.out)?;
    let mut frames = Vec::new();
    for (i, c) in cameras.iter().enumerate() {
        frames.push(shoot(c)?);
        eprint!("\rrendered {}/{}", i + 1, cameras.len());
    }
    eprintln!();
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
    let device = a.device.device();
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
        &run.scene(),
        &views,
        code,
        run.masked(),
        &TraceOptions::default(),
        &device,
    )?;
    for e in &evals {
        println!(
            "{}",
            serde_json::json!({"view": e.view, "iou": (e.iou * 10000.0).round() / 10000.0, "psnr_mask": (e.psnr_mask * 1000.0).round() / 1000.0})
        );
    }
    let n = evals.len() as f64;
    println!(
        "{}",
        serde_json::json!({
            "mean": true,
            "views": evals.len(),
            "iou": (evals.iter().map(|e| e.iou).sum::<f64>() / n * 10000.0).round() / 10000.0,
            "psnr_mask": (evals.iter().map(|e| e.psnr_mask).sum::<f64>() / n * 1000.0).round() / 1000.0,
        })
    );
    Ok(())
}

#[derive(Args, Debug)]
pub struct ExportMesh {
    /// Run folder written by `train idr`.
    #[arg(long)]
    run: PathBuf,
    /// Samples per axis of the grid marching cubes runs on.
    #[arg(long, default_value_t = 256)]
    resolution: usize,
    /// Style weights for the vertex colours (stylized runs).
    #[arg(long, value_delimiter = ',')]
    mix: Option<Vec<f32>>,
    /// Output .ply.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    device: DeviceArgs,
}

pub fn export_mesh(a: ExportMesh) -> Result<()> {
    if a.out
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .as_deref()
        != Some("ply")
    {
        bail!("{}: meshes are written as .ply", a.out.display());
    }
    ins_models::idr::mesh::check_resolution(a.resolution)?;
    let device = a.device.device();
    let run = IdrRun::load(&a.run, &device)?;
    let code = run.code(a.mix.as_deref(), &device)?;
    let (mesh, colors) = extract_mesh(&run.model.valid(), a.resolution, code, &device)?;
    if mesh.triangles.is_empty() {
        bail!(
            "{}: the SDF has no zero level set inside the unit sphere (nothing to mesh)",
            a.run.display()
        );
    }
    ins_io::write_atomic_with(&a.out, |tmp| -> Result<()> {
        let mut f = std::io::BufWriter::new(
            std::fs::File::create(tmp).with_context(|| format!("writing {}", a.out.display()))?,
        );
        mesh.write_ply(&mut f, &colors)
            .with_context(|| format!("writing {}", a.out.display()))
    })?;
    println!(
        "{}",
        serde_json::json!({"mesh": a.out, "vertices": mesh.vertices.len(), "triangles": mesh.triangles.len(), "area": mesh.area(), "volume": mesh.volume()})
    );
    Ok(())
}
