//! The whole evaluation of a stylized 3D run (what `ins-cli eval consistency` runs and the
//! report reads): a camera path rendered by the stylized run and its pretrained run, the
//! frames warped into their neighbours, Gram and content distances per view, the painting's
//! texture on the object against Gatys' method run to convergence, and optionally the per-view
//! 2D baseline; everything written into one folder with `summary.json`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, StyleLoss, StyleTarget};
use ins_core::train::plot::plot_strength_consistency;
use ins_scene::paths::PathKind;
use serde_json::json;
use vgg_import::Vgg;

use super::texture_table::{TextureSets, TextureTable, round};
use super::{
    PaintingFeatures, PathRenders, RANGES, SetScores, StylizedPair, content_features, score_frames,
};
use crate::run::PathFrame;
use crate::stylize2d::{FrameRun, Stylize2dSettings, stylize_frames};
use crate::video::{FrameOutput, write_frames};

/// Default steps per frame of the 2D baseline: on lego at 200×200, 12 steps bring its Gram
/// distance to 2.9e5 (20 steps: 2.4e5; the stylized NeRF: 1.6e6) in 60 % of the time, which
/// keeps a 60-frame evaluation with the baseline under 10 minutes on 2 cores.
pub const BASELINE_STEPS: usize = 12;
/// Default learning rate of the 2D baseline.
pub const BASELINE_LR: f64 = 0.07;
/// Default number of views of the texture measure.
pub const REFERENCE_VIEWS: usize = 4;
/// Default steps of the converged 2D reference.
pub const REFERENCE_STEPS: usize = 300;
/// Learning rate of the converged 2D reference (pixel units): lower than the baseline's, as
/// the reference runs long enough to settle.
pub const REFERENCE_LR: f64 = 0.02;
/// Default frames of the path.
pub const FRAMES: usize = 60;

/// What to evaluate and how.
#[derive(Debug, Clone)]
pub struct ConsistencyOptions {
    /// Camera path (default: the scene's, [`StylizedPair::default_path`]).
    pub path: Option<PathKind>,
    /// Frames of the path.
    pub frames: usize,
    /// Frame size (default: the run's training resolution).
    pub size: Option<(usize, usize)>,
    /// Which painting of a multi-style run the frames are scored against.
    pub style: usize,
    /// The mix the frames are rendered in (default: the painting `style` alone).
    pub mix: Option<Vec<f32>>,
    /// Also stylize each pretrained frame on its own in 2D and score it the same way.
    pub baseline2d: bool,
    /// Steps per frame of the 2D baseline.
    pub baseline_steps: usize,
    /// Adam learning rate of the 2D baseline, in pixel units.
    pub baseline_lr: f64,
    /// Views of the path at which the texture is measured (0: no texture measure, and no 2D
    /// reference to converge).
    pub reference_views: usize,
    /// Steps of the converged 2D reference per view.
    pub reference_steps: usize,
    /// Output folder (default: `RUN/consistency`).
    pub out: Option<PathBuf>,
}

impl Default for ConsistencyOptions {
    fn default() -> Self {
        Self {
            path: None,
            frames: FRAMES,
            size: None,
            style: 0,
            mix: None,
            baseline2d: false,
            baseline_steps: BASELINE_STEPS,
            baseline_lr: BASELINE_LR,
            reference_views: REFERENCE_VIEWS,
            reference_steps: REFERENCE_STEPS,
            out: None,
        }
    }
}

/// How an evaluation reports its progress.
pub trait Progress {
    /// A stage starts (one line for a person).
    fn note(&mut self, message: &str);
    /// `done` of `total` path frames rendered (by both runs).
    fn rendered(&mut self, done: usize, total: usize);
}

/// An evaluation's results: the summary written to `summary.json` and each set's line.
pub struct Evaluation {
    /// The folder everything was written to.
    pub out: PathBuf,
    /// `summary.json`'s content.
    pub summary: serde_json::Value,
    /// Per set of frames, its warp errors and mean distances.
    pub sets: Vec<serde_json::Value>,
}

/// Evaluates the stylized NeRF or IDR run `pair` (see the module's doc), writing the frames,
/// GIFs, `pairs.jsonl`, `views.jsonl`, `strength_consistency.png` and `summary.json` to
/// `options.out`.
pub fn evaluate(
    pair: &StylizedPair,
    options: &ConsistencyOptions,
    vgg: &Vgg,
    device: &Device,
    progress: &mut dyn Progress,
) -> Result<Evaluation> {
    let started = std::time::Instant::now();
    let longest = *RANGES.iter().max().expect("ranges");
    if options.frames <= longest {
        bail!(
            "--frames {}: at least {} frames are needed for the long range (k = {longest})",
            options.frames,
            longest + 1
        );
    }
    let run = pair.student.dir();
    let from = pair
        .student
        .base_run()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let style_args = pair.student.style().clone();
    let styles = &style_args.styles;
    let painting_path = pair.painting(options.style)?;
    let painting = RgbImage::load(painting_path)?;
    let mix = match &options.mix {
        Some(m) => m.clone(),
        None => {
            let mut one = vec![0.0f32; styles.len()];
            one[options.style] = 1.0;
            one
        }
    };
    let code = pair.student.code(Some(&mix), device)?;
    let out = options
        .out
        .clone()
        .unwrap_or_else(|| run.join("consistency"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;

    let cameras: Vec<_> = pair
        .cameras(options.path, options.frames)?
        .iter()
        .map(|c| match options.size {
            Some((w, h)) => c.resized(w as u32, h as u32),
            None => c.clone(),
        })
        .collect();
    let (w, h) = (cameras[0].width, cameras[0].height);
    let total = cameras.len();
    progress.note(&format!(
        "rendering {total} frames ({w}×{h}) of {} and its pretrained run",
        run.display()
    ));
    let render_started = std::time::Instant::now();
    let renders =
        PathRenders::render(pair, cameras, code, device, |i| progress.rendered(i, total))?;
    let render_seconds = render_started.elapsed().as_secs_f64();
    let geometry = renders.geometry();
    let pretrained: Vec<RgbImage> = renders.pretrained.iter().map(|r| r.image.clone()).collect();
    let stylized: Vec<RgbImage> = renders.stylized.iter().map(|r| r.image.clone()).collect();
    write_set(&out, "pretrained", &pretrained)?;
    write_set(&out, "stylized", &stylized)?;
    // Depth before and after stylization, at four frames around the path.
    let picks: Vec<usize> = (0..4).map(|i| i * renders.cameras.len() / 4).collect();
    let depth = |v: &[PathFrame]| {
        RgbImage::hstack(
            &picks
                .iter()
                .map(|&i| v[i].depth_picture.clone())
                .collect::<Vec<_>>(),
        )
    };
    depth(&renders.pretrained).save(&out.join("depth_pretrained.png"))?;
    depth(&renders.stylized).save(&out.join("depth_stylized.png"))?;
    painting.fit_within(256).save(&out.join("painting.png"))?;

    // Gatys' per-view method matches Gram matrices; the run's weights carry over where the run
    // did too.
    let gatys_weights = {
        let (cw, sw) = match style_args.loss() {
            StyleLoss::Gram => (style_args.content_weight, style_args.style_weight),
            _ => (None, None),
        };
        LossWeights::or_defaults(vgg.preprocess, StyleLoss::Gram, cw, sw)
    };
    let gatys = |steps: usize, lr: f64, inputs: &[usize], dir: &str| -> Result<Vec<RgbImage>> {
        let settings = Stylize2dSettings {
            steps,
            lr,
            weights: gatys_weights,
            style_size: style_args.style_size,
            style_loss: StyleLoss::Gram,
            match_radius: None,
        };
        let names = frame_names(pretrained.len());
        let paths: Vec<PathBuf> = inputs
            .iter()
            .map(|&i| out.join("pretrained").join(&names[i]))
            .collect();
        let each = FrameRun {
            style: &painting,
            vgg,
            settings: &settings,
            quiet: true,
            keep_runs: false,
            device,
        };
        let written = stylize_frames(&paths, &out.join(dir), |p: &Path| RgbImage::load(p), &each)?;
        written.iter().map(|p| RgbImage::load(p)).collect()
    };
    let mut baseline_seconds = None;
    let mut baseline = None;
    if options.baseline2d {
        let b_started = std::time::Instant::now();
        progress.note(&format!(
            "per-view 2D baseline: {} frames, {} steps each",
            pretrained.len(),
            options.baseline_steps
        ));
        let all: Vec<usize> = (0..pretrained.len()).collect();
        let frames = gatys(
            options.baseline_steps,
            options.baseline_lr,
            &all,
            "baseline2d",
        )?;
        write_frames(
            &frames,
            &frame_names(frames.len()),
            &FrameOutput::for_path(&out.join("baseline2d.gif"))?,
            12,
        )?;
        baseline_seconds = Some(b_started.elapsed().as_secs_f64());
        baseline = Some(frames);
    }

    progress.note(&format!(
        "scoring: warps at k = {RANGES:?}, Gram and content distances per view"
    ));
    let targets = StyleTarget::stacked_from_images(
        vgg,
        std::slice::from_ref(&painting),
        style_args.style_size,
        device,
    );
    let reference = content_features(vgg, &pretrained, device);
    let score = |set: &str, frames: &[RgbImage]| {
        score_frames(set, &geometry, frames, &reference, vgg, &targets, device)
    };
    let mut sets = vec![score("stylized", &stylized)];
    if let Some(b) = &baseline {
        sets.push(score("baseline2d", b));
    }
    sets.push(score("pretrained", &pretrained));

    // Texture on the object, at a handful of views, against Gatys run to convergence there
    // (none asked for: no texture measure).
    let mut reference_seconds = 0.0;
    let texture = if options.reference_views == 0 {
        None
    } else {
        let views = reference_views(pretrained.len(), options.reference_views);
        let r_started = std::time::Instant::now();
        progress.note(&format!(
            "converged 2D reference: {} views, {} steps each",
            views.len(),
            options.reference_steps
        ));
        let converged = gatys(options.reference_steps, REFERENCE_LR, &views, "reference2d")?;
        reference_seconds = r_started.elapsed().as_secs_f64();
        Some(TextureTable::score(
            vgg,
            &PaintingFeatures::new(vgg, &painting, style_args.style_size, device),
            &renders,
            &views,
            TextureSets {
                stylized: &stylized,
                baseline: baseline.as_deref(),
                converged: &converged,
            },
            device,
        ))
    };

    write_pairs(&out.join("pairs.jsonl"), &sets)?;
    write_views(&out.join("views.jsonl"), &sets)?;
    let (depth_error, opacity_agreement) = renders.depth_agreement();
    let mut summary = json!({
        "run": run,
        "pretrained_run": from,
        "painting": painting_path,
        "mix": crate::style_mix::normalized(styles.len(), Some(&mix))?,
        "path": options.path.unwrap_or(pair.default_path()).name(),
        "frames": renders.cameras.len(),
        "size": [w, h],
        "ranges": RANGES,
        "depth_rel_error_median": depth_error,
        "opacity_agreement": round(opacity_agreement, 4),
        "sets": sets.iter().map(set_line).collect::<Vec<_>>(),
        "texture": texture.as_ref().map(TextureTable::to_json),
        "render_seconds": round(render_seconds, 1),
        "reference2d_seconds": round(reference_seconds, 1),
        "reference2d_steps": options.reference_steps,
    });
    if let Some(s) = baseline_seconds {
        summary["baseline2d_seconds"] = round(s, 1).into();
        summary["baseline2d_steps"] = options.baseline_steps.into();
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
    if let Some(texture) = &texture {
        plot_strength_consistency(
            &texture.strength_points(&sets),
            &out.join("strength_consistency.png"),
        )?;
    }
    Ok(Evaluation {
        out,
        summary,
        sets: sets.iter().map(set_line).collect(),
    })
}

fn frame_names(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("frame_{i:04}.png")).collect()
}

/// A set of frames as a folder of PNGs and a GIF beside it.
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

/// `n` frames spread evenly over a path of `frames` (none past the end).
fn reference_views(frames: usize, n: usize) -> Vec<usize> {
    let n = n.clamp(1, frames.max(1));
    (0..n).map(|i| (2 * i + 1) * frames / (2 * n)).collect()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_views_are_spread_and_inside_the_path() {
        assert_eq!(reference_views(60, 4), vec![7, 22, 37, 52]);
        assert_eq!(reference_views(3, 10), vec![0, 1, 2]);
        assert_eq!(reference_views(10, 1), vec![5]);
    }
}
