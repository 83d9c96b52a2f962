//! `ins-cli eval consistency`: how consistent a stylized NeRF is across views, against the
//! per-view 2D baseline and the unstylized floor, with style and content distances per view.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use ins_core::backend::BackendChoice;
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, StyleTarget};
use ins_models::nerf::NerfRun;
use ins_models::nerf::consistency::{
    PathRenders, RANGES, SetScores, content_features, score_frames,
};
use ins_models::stylize2d::Stylize2dSettings;
use serde_json::json;

use crate::siren_cmd::parse_size;
use crate::stylize2d_cmd::{FrameRun, stylize_frames};
use crate::vgg_cmd::VggArgs;
use crate::video::{FrameOutput, write_frames};

/// Default steps per frame of the 2D baseline: on lego at 200×200, 12 steps bring its Gram
/// distance to 2.9e5 (20 steps: 2.4e5; the stylized NeRF: 1.6e6) in 60 % of the time, which
/// keeps a 60-frame evaluation with the baseline under 10 minutes on 2 cores.
pub const BASELINE_STEPS: usize = 12;
/// Default learning rate of the 2D baseline.
pub const BASELINE_LR: f64 = 0.07;

#[derive(Args, Debug)]
pub struct EvalConsistency {
    /// A stylized NeRF run (written by `train nerf --from`).
    #[arg(long)]
    pub run: PathBuf,
    /// Camera path: spiral or turntable (default: spiral for forward-facing scenes, turntable
    /// for the others).
    #[arg(long)]
    pub path: Option<String>,
    /// Frames of the path.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Frame size WxH (default: the run's training resolution).
    #[arg(long)]
    pub size: Option<String>,
    /// Which style of a multi-style run (index into its --style list).
    #[arg(long, default_value_t = 0)]
    pub style: usize,
    /// Also stylize the pretrained frames one by one in 2D with the same painting (the per-view
    /// baseline), and score them the same way.
    #[arg(long)]
    pub baseline2d: bool,
    /// Optimisation steps per frame of the 2D baseline (with the learning rate below, 12 steps
    /// bring a 200×200 frame most of the way: the Gram distance falls below the stylized
    /// NeRF's).
    #[arg(long, default_value_t = BASELINE_STEPS)]
    pub baseline_steps: usize,
    /// Adam learning rate of the 2D baseline, in pixel units.
    #[arg(long, default_value_t = BASELINE_LR)]
    pub baseline_lr: f64,
    /// Output folder: frames, GIFs, pairs.jsonl, views.jsonl, summary.json (default:
    /// RUN/consistency). Baseline frames already there are kept.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Backend.
    #[arg(long, default_value = "auto")]
    pub backend: BackendChoice,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub vgg: VggArgs,
}

fn frame_names(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("frame_{i:04}.png")).collect()
}

fn write_set(dir: &Path, name: &str, frames: &[RgbImage]) -> Result<()> {
    let names = frame_names(frames.len());
    write_frames(frames, &names, &FrameOutput::Folder(dir.join(name)), 12)?;
    write_frames(
        frames,
        &names,
        &FrameOutput::for_path(&dir.join(format!("{name}.gif")))?,
        12,
    )?;
    Ok(())
}

fn round(x: f64, digits: i32) -> f64 {
    let f = 10f64.powi(digits);
    (x * f).round() / f
}

fn set_line(s: &SetScores) -> serde_json::Value {
    let mut line = json!({
        "set": s.set,
        "gram_distance": round(s.mean_gram(), 1),
        "content_distance": round(s.mean_content(), 1),
    });
    for (k, r) in RANGES.iter().zip(&s.rmse) {
        line[format!("rmse_k{k}")] = r.map(|v| round(v, 5)).into();
    }
    line
}

pub fn run(a: EvalConsistency) -> Result<()> {
    let started = std::time::Instant::now();
    if a.frames <= *RANGES.iter().max().expect("ranges") {
        bail!(
            "--frames {}: at least {} frames are needed for the long range (k = {})",
            a.frames,
            RANGES.iter().max().expect("ranges") + 1,
            RANGES.iter().max().expect("ranges")
        );
    }
    let backend = a.backend.resolve();
    let device = backend.device();
    let student = NerfRun::load(&a.run, &device)?;
    let from = match (&student.base, &student.config.from) {
        (Some(_), Some(from)) => from.clone(),
        _ => bail!(
            "{} is a pretrained run: view consistency is measured on a stylized run \
             (`ins-cli train nerf --from {} --style PAINTING`)",
            a.run.display(),
            a.run.display()
        ),
    };
    let teacher = NerfRun::load(&from, &device)
        .with_context(|| format!("the pretrained run of {}", a.run.display()))?;
    let styles = &student.config.styles;
    let painting_path = styles.get(a.style).with_context(|| {
        format!(
            "--style {}: {} has {} style{}",
            a.style,
            a.run.display(),
            styles.len(),
            if styles.len() == 1 { "" } else { "s" }
        )
    })?;
    let painting = RgbImage::load(painting_path)?;
    let mut mix = vec![0.0f32; styles.len()];
    mix[a.style] = 1.0;
    let code = student.code(Some(&mix), &device)?;
    let vgg = a.vgg.load(&device)?;
    let out = a.out.clone().unwrap_or_else(|| a.run.join("consistency"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;

    let size = a.size.as_deref().map(parse_size).transpose()?;
    let cameras: Vec<_> = crate::nerf_cmd::path_cameras(&student, a.path.as_deref(), a.frames)?
        .iter()
        .map(|c| crate::view_size::resized(c, size))
        .collect();
    let (w, h) = (cameras[0].width, cameras[0].height);
    eprintln!(
        "rendering {} frames ({w}×{h}) of {} and its pretrained run on {backend}",
        cameras.len(),
        a.run.display()
    );
    let render_started = std::time::Instant::now();
    let renders = PathRenders::render(&student, &teacher, cameras, code, &device, |i| {
        if !a.quiet {
            eprint!("\rrendered {i}/{}", a.frames);
        }
    })?;
    if !a.quiet {
        eprintln!();
    }
    let render_seconds = render_started.elapsed().as_secs_f64();
    let geometry = renders.geometry(&teacher);
    let pretrained: Vec<RgbImage> = renders.pretrained.iter().map(|r| r.image()).collect();
    let stylized: Vec<RgbImage> = renders.stylized.iter().map(|r| r.image()).collect();
    write_set(&out, "pretrained", &pretrained)?;
    write_set(&out, "stylized", &stylized)?;
    // Depth before and after stylization, at four frames around the path.
    let picks: Vec<usize> = (0..4).map(|i| i * renders.cameras.len() / 4).collect();
    let depth = |v: &[ins_models::nerf::eval::ViewRender]| {
        RgbImage::hstack(
            &picks
                .iter()
                .map(|&i| v[i].depth_picture())
                .collect::<Vec<_>>(),
        )
    };
    depth(&renders.pretrained).save(&out.join("depth_pretrained.png"))?;
    depth(&renders.stylized).save(&out.join("depth_stylized.png"))?;
    painting.fit_within(256).save(&out.join("painting.png"))?;

    let mut baseline_seconds = None;
    let mut baseline = None;
    if a.baseline2d {
        let b_started = std::time::Instant::now();
        let settings = Stylize2dSettings {
            steps: a.baseline_steps,
            lr: a.baseline_lr,
            weights: LossWeights::or_defaults(
                vgg.preprocess,
                student.config.content_weight,
                student.config.style_weight,
            ),
            style_size: student.config.style_size,
        };
        eprintln!(
            "2D baseline: stylizing {} frames one by one, {} steps each",
            pretrained.len(),
            a.baseline_steps
        );
        let inputs: Vec<PathBuf> = frame_names(pretrained.len())
            .iter()
            .map(|n| out.join("pretrained").join(n))
            .collect();
        let each = FrameRun {
            style: &painting,
            vgg: &vgg,
            settings: &settings,
            quiet: true,
            keep_runs: false,
            device: &device,
        };
        let written = stylize_frames(
            &inputs,
            &out.join("baseline2d"),
            |p: &Path| RgbImage::load(p),
            &each,
        )?;
        let frames = written
            .iter()
            .map(|p| RgbImage::load(p))
            .collect::<Result<Vec<_>>>()?;
        write_frames(
            &frames,
            &frame_names(frames.len()),
            &FrameOutput::for_path(&out.join("baseline2d.gif"))?,
            12,
        )?;
        baseline_seconds = Some(b_started.elapsed().as_secs_f64());
        baseline = Some(frames);
    }

    eprintln!("scoring: warps at k = {RANGES:?}, Gram and content distances per view");
    let targets = StyleTarget::stacked_from_images(
        &vgg,
        std::slice::from_ref(&painting),
        student.config.style_size,
        &device,
    );
    let reference = content_features(&vgg, &pretrained, &device);
    let mut sets = vec![score_frames(
        "stylized", &geometry, &stylized, &reference, &vgg, &targets, &device,
    )];
    if let Some(b) = &baseline {
        sets.push(score_frames(
            "baseline2d",
            &geometry,
            b,
            &reference,
            &vgg,
            &targets,
            &device,
        ));
    }
    sets.push(score_frames(
        "pretrained",
        &geometry,
        &pretrained,
        &reference,
        &vgg,
        &targets,
        &device,
    ));

    write_pairs(&out.join("pairs.jsonl"), &sets)?;
    write_views(&out.join("views.jsonl"), &sets)?;
    let (depth_error, opacity_agreement) = renders.depth_agreement();
    let mut summary = json!({
        "run": a.run,
        "pretrained_run": from,
        "painting": painting_path,
        "path": a.path.as_deref().unwrap_or(crate::nerf_cmd::default_path(&student)),
        "frames": renders.cameras.len(),
        "size": [w, h],
        "ranges": RANGES,
        "depth_rel_error_median": depth_error,
        "opacity_agreement": round(opacity_agreement, 4),
        "sets": sets.iter().map(set_line).collect::<Vec<_>>(),
        "render_seconds": round(render_seconds, 1),
    });
    if let Some(s) = baseline_seconds {
        summary["baseline2d_seconds"] = round(s, 1).into();
        summary["baseline2d_steps"] = a.baseline_steps.into();
        let (st, b) = (&sets[0], &sets[1]);
        for (i, k) in RANGES.iter().enumerate() {
            if let (Some(s), Some(b)) = (st.rmse[i], b.rmse[i]) {
                summary[format!("baseline_over_stylized_k{k}")] = round(b / s.max(1e-12), 3).into();
            }
        }
    }
    summary["seconds"] = round(started.elapsed().as_secs_f64(), 1).into();
    ins_io::write_atomic(
        &out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    for s in &sets {
        println!("{}", set_line(s));
    }
    println!("{summary}");
    eprintln!(
        "wrote {}/summary.json, pairs.jsonl, views.jsonl and the frames",
        out.display()
    );
    Ok(())
}

fn write_jsonl(path: &Path, lines: impl Iterator<Item = serde_json::Value>) -> Result<()> {
    let text: String = lines.map(|l| format!("{l}\n")).collect();
    Ok(ins_io::write_atomic(path, text.as_bytes())?)
}

fn write_pairs(path: &Path, sets: &[SetScores]) -> Result<()> {
    write_jsonl(
        path,
        sets.iter().flat_map(|s| {
            RANGES.iter().zip(&s.pairs).flat_map(move |(k, pairs)| {
                pairs.iter().map(move |p| {
                    json!({"set": s.set, "k": k, "from": p.from, "to": p.to,
                           "rmse": p.rmse.map(|v| round(v, 5)), "pixels": p.pixels})
                })
            })
        }),
    )
}

fn write_views(path: &Path, sets: &[SetScores]) -> Result<()> {
    write_jsonl(
        path,
        sets.iter().flat_map(|s| {
            (0..s.gram_distance.len()).map(move |i| {
                json!({"set": s.set, "frame": i,
                       "gram_distance": round(s.gram_distance[i], 1),
                       "content_distance": round(s.content_distance[i], 1)})
            })
        }),
    )
}
