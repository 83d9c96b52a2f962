//! `ins-cli stylize`: from a folder of photos and a painting to a video, a report and a mesh in
//! one command. It runs the stages a user would otherwise chain by hand (`data sfm`,
//! `train nerf|idr --scene`, `train … --from … --style`, `eval consistency`, `report`,
//! `export mesh`) into one folder:
//!
//! ```text
//! OUT/stylize.json   what each stage ran on and whether it finished (see `stages`)
//! OUT/scene/         poses from structure from motion, for plain photos
//! OUT/pretrained/    the scene learned from its photos
//! OUT/stylized/      the same in the painting's style
//! OUT/renders/       the camera path as MP4 (GIF without ffmpeg), the stylized mesh
//! OUT/report/        one HTML page: painting, views, animations, depth, numbers
//! ```
//!
//! Running the same command again continues where it stopped: finished stages are kept, a
//! killed training resumes from its checkpoint, and a changed input redoes only what depends
//! on it (another painting keeps the poses and the pretraining).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use ins_core::imaging::RgbImage;
use ins_models::consistency::ConsistencyOptions;
use ins_models::idr::{Idr, IdrRunConfig};
use ins_models::mesh_export::{MeshFormat, MeshFrame, export_mesh};
use ins_models::nerf::{Nerf, NerfRunConfig};
use ins_models::run::scene::load_scene;
use ins_models::run::{MeshOptions, RunKind};
use ins_models::video::{FrameOutput, ffmpeg_available, write_frames};
use ins_scene::data::SceneFormat;

use crate::common::{DeviceArgs, RunArgs, TrainCommand, VggArgs};
use crate::stages::{Fingerprint, Manifest, StageCounter, StageStart, describe, minutes};
use crate::stylize_inputs::{MIN_PHOTOS, Photos, check_free_space, scene_files, what_photos};

/// How much slower a stylizing step is than a pretraining step of the same scene, where the
/// pretrained run does not say how many rays its steps took (and for surfaces): lego at 200²
/// on 2 cores, 0.46 s against 1.1 s a step (docs/results.md). Only for the estimate of what
/// is left.
const STYLIZE_STEP_COST: f64 = 2.4;
/// A NeRF stylizing step's VGG-16 pass, forward and back, in pretraining steps: with the
/// default 64² patch shaded as `64² / rays` pretraining batches, this gives lego's 2.4 (about
/// 6,000 rays a step) and 8.8 for a synthetic room capture that took 9.9 (576 rays a step,
/// 223 samples each: 6.3 s against 0.63 s a step, docs/measurements.md).
const STYLIZE_VGG_COST: f64 = 1.7;
/// Fewest pretraining steps of a `--quick` preview: a room capture of 50 photos at 200×150
/// pretrained for a quarter of its 1000 steps stayed fog (17.21 dB held out, the objects
/// gone: a preview that shows nothing to stylize); for 500, 22.58 dB with the objects clear
/// (docs/measurements.md). fern's quarter is 500 already.
const QUICK_MIN_PRETRAIN_STEPS: usize = 500;

/// [`STYLIZE_STEP_COST`], or for NeRF the pretrained run's own: its patch of 64² rays against
/// the rays of its pretraining steps (the samples a ray are the scene's either way).
fn stylize_step_cost(pretrained: &Path, surface: bool) -> f64 {
    let rays = crate::report_cmd::last_with(pretrained, "rays").and_then(|v| v["rays"].as_f64());
    match rays {
        Some(rays) if !surface && rays > 0.0 => 64.0 * 64.0 / rays + STYLIZE_VGG_COST,
        _ => STYLIZE_STEP_COST,
    }
}

#[derive(Args, Debug)]
pub struct Stylize {
    /// Photos of one scene: a folder of plain photos (posed by structure from motion), or a
    /// scene folder (a COLMAP workspace, a transforms.json capture, Blender, LLFF, DTU).
    #[arg(long, value_name = "DIR")]
    photos: PathBuf,
    /// A painting; repeat for several, learned in one model and mixed at will when rendering.
    #[arg(long = "style", value_name = "IMAGE", required = true)]
    styles: Vec<PathBuf>,
    /// Output folder: scene/, pretrained/, stylized/, renders/, report/ (see `ins-cli stylize
    /// --help`); running the same command again continues in it.
    #[arg(long)]
    out: PathBuf,
    /// Reconstruct a surface (IDR) instead of a radiance field: the photos need object masks.
    #[arg(long)]
    surface: bool,
    /// A preview, to choose a painting: a quarter of the steps (pretraining at least 500),
    /// images half as large, half the frames and smaller, a coarser mesh.
    #[arg(long)]
    quick: bool,
    /// Pretraining steps (default: the variant's for the scene; --quick: a quarter, at least
    /// 500).
    #[arg(long)]
    pretrain_steps: Option<usize>,
    /// Stylization steps (default: the variant's; --quick: a quarter).
    #[arg(long)]
    stylize_steps: Option<usize>,
    /// Image downscale factor (default: the long side near 400 px; --quick: near 200).
    #[arg(long)]
    downscale: Option<u32>,
    /// Frames of the video (and of the report's views; --quick: half).
    #[arg(long, default_value_t = 36)]
    frames: usize,
    /// Longer side of the video's frames in pixels (--quick: 5/8 of it). Rendering a frame on
    /// 2 CPU cores takes about a minute at 500×375 for a stylized field, a quarter at 256.
    #[arg(long, default_value_t = 256)]
    video_size: u32,
    /// Samples along the longest side of the mesh's grid (default 256; --quick: 128).
    #[arg(long)]
    mesh_resolution: Option<usize>,
    /// COLMAP camera model for plain photos.
    #[arg(long, default_value = "SIMPLE_RADIAL")]
    camera_model: String,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
    #[command(flatten)]
    device: DeviceArgs,
    #[command(flatten)]
    vgg: VggArgs,
}

/// The configuration of a stage's run, of either variant.
enum AnyConfig<'a> {
    Nerf(&'a NerfRunConfig),
    Idr(&'a IdrRunConfig),
}

/// The stages, in order.
const STAGES: [&str; 4] = ["poses", "pretrain", "stylize", "outputs"];

impl Stylize {
    /// The settings a preview scales down: a quarter of the steps (0: the variant's default,
    /// itself scaled at resolve time through `steps_or_quarter`), the long side near 200 px.
    fn downscale(&self, photos_dir: &Path) -> Result<u32> {
        if let Some(d) = self.downscale {
            return Ok(d);
        }
        if !self.quick {
            return Ok(0);
        }
        let (w, h) = ins_scene::data::Scene::probe_resolution(photos_dir)?;
        let d = ins_models::run::scene::auto_downscale(
            w,
            h,
            ins_models::run::scene::DEFAULT_LONG_SIDE / 2,
        );
        // An LLFF folder shrinks only from the folders it has (fern: images_8/ alone).
        if d > 1
            && ins_scene::data::detect_format(photos_dir)? == SceneFormat::Llff
            && !photos_dir.join(format!("images_{d}")).is_dir()
            && !photos_dir.join("images").is_dir()
        {
            eprintln!(
                "--quick: {} has neither images_{d}/ nor images/ to bring its {w}×{h} photos \
                 near 200 px: they stay at that size",
                photos_dir.display()
            );
            return Ok(0);
        }
        Ok(d)
    }

    /// `steps`, or the variant's `default` (a quarter of it with --quick).
    fn steps(&self, steps: Option<usize>, default: usize) -> usize {
        steps.unwrap_or(if self.quick {
            default.div_ceil(4)
        } else {
            default
        })
    }

    /// `--pretrain-steps`, or [`Self::steps`] of the variant's `default`, never fewer than
    /// [`QUICK_MIN_PRETRAIN_STEPS`] (nor than `default`).
    fn pretrain_steps_or(&self, default: usize) -> usize {
        self.pretrain_steps.unwrap_or_else(|| {
            self.steps(None, default)
                .max(QUICK_MIN_PRETRAIN_STEPS.min(default))
        })
    }

    /// Trains `cfg` into `out` as `ins-cli train` does (resuming where `resume` says); its steps.
    fn train_stage(
        &self,
        out: &Path,
        resume: bool,
        cfg: AnyConfig,
        what: &str,
        next: &str,
    ) -> Result<usize> {
        // The report shows the views along the camera path; the held-out views rendered
        // again at the end of each run (2 min of a stylizing stage on a 50-photo capture at
        // 400×300) would be seen by no one.
        let run = RunArgs {
            config: None,
            resume,
            quiet: self.quiet,
            final_pictures: false,
        };
        let cmd = TrainCommand {
            out,
            run: &run,
            device: &self.device,
            vgg: &self.vgg,
        };
        Ok(match cfg {
            AnyConfig::Nerf(c) => {
                cmd.train::<Nerf>(c, c.schedule.checkpoint_every, what, next)?
                    .steps
            }
            AnyConfig::Idr(c) => {
                cmd.train::<Idr>(c, c.schedule.checkpoint_every, what, next)?
                    .steps
            }
        })
    }

    /// The size of the video's frames: the camera path's (the first view's) shape, the longer
    /// side [`Self::video_size`] (never larger than the photos).
    fn frame_size(&self, scene_dir: &Path) -> Result<(usize, usize)> {
        let (w, h) = ins_scene::data::Scene::probe_resolution(scene_dir)?;
        let long = if self.quick {
            self.video_size * 5 / 8
        } else {
            self.video_size
        };
        let s = (long as f64 / w.max(h).max(1) as f64).min(1.0);
        let side = |v: u32| ((v as f64 * s).round() as usize).max(8);
        Ok((side(w), side(h)))
    }

    /// The mesh grid's longest side: [`Self::mesh_resolution`], or 256 (a preview's 128: an
    /// eighth of the density queries, about 9 s less on a 50-photo capture).
    fn mesh_resolution(&self) -> usize {
        self.mesh_resolution
            .unwrap_or(if self.quick { 128 } else { 256 })
    }

    fn frames(&self) -> usize {
        let frames = if self.quick {
            self.frames.div_ceil(2)
        } else {
            self.frames
        };
        // The report's consistency measure compares frames seven apart.
        frames.max(8)
    }
}

pub fn run(a: Stylize) -> Result<()> {
    let started = Instant::now();
    // Everything a long stage would stop on is checked first.
    for s in &a.styles {
        RgbImage::load(s).with_context(|| format!("--style {}", s.display()))?;
    }
    let photos = what_photos(&a.photos)?;
    check_free_space(&a.out)?;
    let backend = a.device.backend.resolve();
    let device = backend.try_device()?;
    let variant = if a.surface { "IDR" } else { "NeRF" };
    let mut manifest = Manifest::load(&a.out)?;

    let painting_names: Vec<String> = a.styles.iter().map(|p| p.display().to_string()).collect();
    eprintln!(
        "stylizing {} with {} into {} on {backend}{}",
        a.photos.display(),
        painting_names.join(", "),
        a.out.display(),
        if a.quick {
            " (a quick preview: a quarter of the steps, pretraining at least 500, images half as large)"
        } else {
            ""
        }
    );
    let first = if matches!(photos, Photos::Plain(_)) {
        0
    } else {
        1
    };
    let plan: Vec<&str> = STAGES[first..].to_vec();
    eprintln!(
        "stages: {}",
        plan.iter()
            .enumerate()
            .map(|(i, s)| format!("{} {}", i + 1, describe(s, variant)))
            .collect::<Vec<_>>()
            .join(" · ")
    );
    let counter = StageCounter {
        plan: plan.clone(),
        started,
    };

    // 1. Poses (plain photos only).
    let (scene_dir, scene_print) = match &photos {
        Photos::Plain(files) => {
            let inputs = Fingerprint::new()
                .text(&a.camera_model)
                .files(files)
                .context("reading the photos")?;
            let dir = a.out.join("scene");
            let t = Instant::now();
            if counter.begin("poses", &manifest, inputs) != StageStart::Kept {
                // Structure from motion has no checkpoint: a stopped one starts again, unless
                // it had written its model before it stopped.
                if !dir.join("sparse/0").exists()
                    || manifest.start_of("poses", inputs) == StageStart::Fresh
                {
                    remove(&dir)?;
                }
                manifest.begin("poses", inputs)?;
                if !dir.join("sparse/0").exists() {
                    let sfm = crate::sfm_cmd::structure_from_motion(
                        &a.photos,
                        &dir,
                        &a.camera_model,
                        a.vgg.cache.as_deref(),
                    )?;
                    if sfm.registered < MIN_PHOTOS {
                        bail!(
                            "{}: structure from motion posed {} of {} photos ({} needed); {}",
                            a.photos.display(),
                            sfm.registered,
                            sfm.photos,
                            MIN_PHOTOS,
                            crate::sfm_cmd::FEW_REGISTERED
                        );
                    }
                    eprintln!(
                        "posed {} of {} photos (mean reprojection error {:.2} px){}",
                        sfm.registered,
                        sfm.photos,
                        sfm.reprojection_error,
                        if sfm.unregistered.is_empty() {
                            String::new()
                        } else {
                            format!("; left out: {}", sfm.unregistered.join(", "))
                        }
                    );
                }
                manifest.finish("poses", t.elapsed().as_secs_f64())?;
            }
            counter.end("poses", &manifest, None);
            (dir, inputs)
        }
        Photos::Scene(format) => {
            let inputs = Fingerprint::new()
                .text(&format!("{format}"))
                .files(&scene_files(&a.photos, &a.out)?)
                .context("reading the scene")?;
            (a.photos.clone(), inputs)
        }
    };

    // 2. Pretraining.
    let downscale = a.downscale(&scene_dir)?;
    let pretrained = a.out.join("pretrained");
    let pretrain_inputs = scene_print
        .text(variant)
        .text(&format!("{:?} {downscale}", a.pretrain_steps))
        .text(&a.quick.to_string());
    let mut pretrain_seconds_per_step = None;
    {
        let t = Instant::now();
        let start = counter.begin("pretrain", &manifest, pretrain_inputs);
        if start != StageStart::Kept {
            if start == StageStart::Fresh {
                remove(&pretrained)?;
            }
            manifest.begin("pretrain", pretrain_inputs)?;
            let resume = start == StageStart::Resumed && pretrained.join("checkpoints").is_dir();
            let what = format!("pretraining {variant} on {}", scene_dir.display());
            let next = "then stylizing";
            let steps = if a.surface {
                let mut cfg = IdrRunConfig::default();
                cfg.source.scene = Some(scene_dir.clone());
                cfg.source.downscale = downscale;
                cfg.schedule.steps = a.pretrain_steps_or(cfg.steps_for(RunKind::Pretrain));
                a.train_stage(&pretrained, resume, AnyConfig::Idr(&cfg), &what, next)?
            } else {
                let mut cfg = NerfRunConfig::default();
                cfg.source.scene = Some(scene_dir.clone());
                cfg.source.downscale = downscale;
                cfg.schedule.steps = match a.pretrain_steps {
                    Some(steps) => steps,
                    None => {
                        // The scene's default (or a quarter of it), which depends on how the
                        // scene is framed.
                        let (scene, _, _) = load_scene(&scene_dir, downscale, None)?;
                        a.pretrain_steps_or(cfg.pretrain_steps_for(scene.forward_facing))
                    }
                };
                cfg.eval_every = held_out_at_the_end(cfg.schedule.steps);
                a.train_stage(&pretrained, resume, AnyConfig::Nerf(&cfg), &what, next)?
            };
            let seconds = t.elapsed().as_secs_f64();
            pretrain_seconds_per_step = Some(seconds / steps.max(1) as f64);
            manifest.finish("pretrain", seconds)?;
        }
        let stylize_steps = a.steps(a.stylize_steps, if a.surface { 400 } else { 600 });
        let cost = stylize_step_cost(&pretrained, a.surface);
        let estimate = pretrain_seconds_per_step.map(|s| s * stylize_steps as f64 * cost);
        counter.end("pretrain", &manifest, estimate);
    }

    // 3. Stylization.
    let stylized = a.out.join("stylized");
    let stylize_inputs = pretrain_inputs
        .files(&a.styles)
        .context("reading the paintings")?
        .text(&format!("{:?}", a.stylize_steps));
    {
        let t = Instant::now();
        let start = counter.begin("stylize", &manifest, stylize_inputs);
        if start != StageStart::Kept {
            if start == StageStart::Fresh {
                remove(&stylized)?;
            }
            manifest.begin("stylize", stylize_inputs)?;
            let resume = start == StageStart::Resumed && stylized.join("checkpoints").is_dir();
            let what = format!("stylizing {variant} with {}", painting_names.join(", "));
            let next = "then the video, the report and the mesh";
            if a.surface {
                let mut cfg = IdrRunConfig::default();
                cfg.source.from = Some(pretrained.clone());
                cfg.style.styles = a.styles.clone();
                cfg.schedule.steps = a.steps(a.stylize_steps, cfg.steps_for(RunKind::Stylize));
                a.train_stage(&stylized, resume, AnyConfig::Idr(&cfg), &what, next)?;
            } else {
                let mut cfg = NerfRunConfig::default();
                cfg.source.from = Some(pretrained.clone());
                cfg.style.styles = a.styles.clone();
                cfg.schedule.steps = a.steps(a.stylize_steps, cfg.steps_for(RunKind::Stylize));
                // A stylized view's PSNR against its photo says little and the report reads
                // none: no held-out views (72 s at the end of a 50-photo capture's stage).
                cfg.eval_views = 0;
                a.train_stage(&stylized, resume, AnyConfig::Nerf(&cfg), &what, next)?;
            }
            manifest.finish("stylize", t.elapsed().as_secs_f64())?;
        }
        counter.end("stylize", &manifest, None);
    }

    // 4. What a user shares: the video, the report, the mesh.
    let renders = a.out.join("renders");
    let report = a.out.join("report");
    let frames = a.frames();
    let frame_size = a.frame_size(&scene_dir)?;
    let outputs_inputs =
        stylize_inputs.text(&format!("{frames} {frame_size:?} {}", a.mesh_resolution()));
    {
        let t = Instant::now();
        let start = counter.begin("outputs", &manifest, outputs_inputs);
        if start != StageStart::Kept {
            remove(&renders)?;
            remove(&report)?;
            manifest.begin("outputs", outputs_inputs)?;
            // The report's evaluation renders the camera path with the stylized run and its
            // pretrained run; the video is its stylized frames. The texture measure against a
            // converged 2D result costs minutes per view: `eval consistency` runs it on demand.
            let options = ConsistencyOptions {
                frames,
                size: Some(frame_size),
                reference_views: 0,
                ..ConsistencyOptions::default()
            };
            let written = crate::report_cmd::write_report(
                &stylized, &report, true, &options, &a.vgg, a.quiet, &device,
            )?;
            write_video(&stylized, &renders)?;
            let mesh = MeshOptions {
                resolution: a.mesh_resolution(),
                level: written.mesh_level,
            };
            // The report meshed the run already (at its own size): where it found no surface,
            // neither would a finer grid, and the report has said why.
            let glb = renders.join("stylized.glb");
            if report.join("mesh.glb").is_file() {
                if let Err(e) = export_mesh(
                    &stylized,
                    mesh,
                    None,
                    MeshFormat::Glb,
                    MeshFrame::Scene,
                    &glb,
                    &device,
                ) {
                    eprintln!("no mesh: {e:#}");
                }
            }
            manifest.finish("outputs", t.elapsed().as_secs_f64())?;
        }
        counter.end("outputs", &manifest, None);
    }
    let video = find_video(&renders).context("the outputs stage wrote no video")?;

    println!(
        "{}",
        serde_json::json!({
            "out": a.out,
            "video": video,
            "report": report.join("index.html"),
            "mesh": renders.join("stylized.glb").is_file().then(|| renders.join("stylized.glb")),
            "stylized_run": stylized,
            "seconds": (started.elapsed().as_secs_f64() * 10.0).round() / 10.0,
        })
    );
    eprintln!("\ndone in {}:", minutes(started.elapsed().as_secs_f64()));
    eprintln!("  video    {}", video.display());
    eprintln!(
        "  report   {} (open it in a browser)",
        report.join("index.html").display()
    );
    let glb = renders.join("stylized.glb");
    if glb.is_file() {
        eprintln!(
            "  mesh     {} (Blender, three.js, Windows' 3D Viewer)",
            glb.display()
        );
    }
    eprintln!(
        "  look around it: ins-cli view --run {}",
        stylized.display()
    );
    Ok(())
}

/// The one command's NeRF runs score their held-out views once, at their last step (`steps`),
/// for the report. Why not every 500 steps, as `train nerf` does: each evaluation renders four
/// held-out views in full, about a minute on 2 cores at ~400 px (fern at 504×378: 62 s of a
/// 644 s, 1000-step pretraining), and the stage checklist already shows the progress.
fn held_out_at_the_end(steps: usize) -> usize {
    steps.max(1)
}

/// Removes a stage's output folder (one this command made inside its output folder).
fn remove(dir: &Path) -> Result<()> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("removing {}", dir.display()))?;
    }
    Ok(())
}

/// The stylized frames of the report's evaluation as a video in `renders`: MP4 where ffmpeg
/// is on PATH, else a GIF, named by the path (turntable, arc, spiral).
fn write_video(stylized: &Path, renders: &Path) -> Result<PathBuf> {
    let eval = stylized.join("consistency");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(eval.join("summary.json")).context("the evaluation's summary")?,
    )?;
    let path = summary["path"].as_str().unwrap_or("path").to_string();
    let frames = summary["frames"].as_u64().unwrap_or(0) as usize;
    let names: Vec<String> = (0..frames).map(|i| format!("frame_{i:04}.png")).collect();
    let images = names
        .iter()
        .map(|n| RgbImage::load(&eval.join("stylized").join(n)))
        .collect::<Result<Vec<_>>>()?;
    std::fs::create_dir_all(renders).with_context(|| format!("creating {}", renders.display()))?;
    let ext = if ffmpeg_available() { "mp4" } else { "gif" };
    let out = renders.join(format!("{path}.{ext}"));
    write_frames(&images, &names, &FrameOutput::for_path(&out)?, 12)?;
    Ok(out)
}

/// The video a finished outputs stage wrote.
fn find_video(renders: &Path) -> Option<PathBuf> {
    let entries = std::fs::read_dir(renders).ok()?;
    entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("mp4" | "gif")))
}
