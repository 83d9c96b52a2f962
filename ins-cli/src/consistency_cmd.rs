//! `ins-cli eval consistency`: how consistent a stylized NeRF or IDR run is across views,
//! against the per-view 2D baseline and the unstylized floor, with style and content distances
//! per view; and how much of the painting's texture reached the object, against Gatys run to
//! convergence on a few of the same views.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use ins_core::eval::feature_match::transfer_ratio;
use ins_core::imaging::RgbImage;
use ins_core::loss::{LossWeights, StyleLoss, StyleTarget};
use ins_core::train::plot::{StrengthPoint, plot_strength_consistency};
use ins_models::consistency::{
    PALETTE_LAYERS, PaintingFeatures, PathFrame, PathRenders, RANGES, SetScores, StylizedPair,
    TEXTURE_LAYERS, content_features, score_frames, texture_distances,
};
use ins_models::stylize2d::Stylize2dSettings;
use ins_scene::paths::PathKind;
use serde_json::json;
use vgg_import::Vgg;

use crate::common::{DeviceArgs, parse_size};
use crate::counter::Counter;
use crate::stylize2d_cmd::{FrameRun, stylize_frames};
use crate::vgg_cmd::VggArgs;
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

#[derive(Args, Debug)]
pub struct EvalConsistency {
    /// A stylized NeRF or IDR run (written by `train nerf|idr --from`).
    #[arg(long)]
    pub run: PathBuf,
    /// Camera path: spiral, turntable or arc (default: spiral for forward-facing scenes, an
    /// arc over the side a partial capture saw, such as DTU's, a turntable for the others).
    #[arg(long)]
    pub path: Option<PathKind>,
    /// Frames of the path.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Frame size WxH (default: the run's training resolution).
    #[arg(long)]
    pub size: Option<String>,
    /// Which style of a multi-style run (index into its --style list): the painting the frames
    /// are scored against, and the one they are rendered in unless --mix says otherwise.
    #[arg(long, default_value_t = 0)]
    pub style: usize,
    /// Render the frames in this mix of a multi-style run's styles (one weight per style, e.g.
    /// `0.25,0.75`), still scored against --style's painting: how far along a mix the texture
    /// of each painting goes. Give --out so that runs of several mixes do not overwrite each other.
    #[arg(long, value_delimiter = ',')]
    pub mix: Option<Vec<f32>>,
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
    /// Views of the path (spread evenly) at which the texture on the object is measured against
    /// Gatys' method run to convergence.
    #[arg(long, default_value_t = REFERENCE_VIEWS)]
    pub reference_views: usize,
    /// Optimisation steps of the converged 2D reference per view.
    #[arg(long, default_value_t = REFERENCE_STEPS)]
    pub reference_steps: usize,
    /// Output folder: frames, GIFs, pairs.jsonl, views.jsonl, summary.json (default:
    /// RUN/consistency). Baseline frames already there are kept.
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub device: DeviceArgs,
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
    let backend = a.device.backend.resolve();
    let device = backend.try_device()?;
    let pair = StylizedPair::load(&a.run, &device)?;
    let from = pair
        .student
        .base_run()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let style_args = pair.student.style().clone();
    let styles = &style_args.styles;
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
    let mix = match &a.mix {
        Some(m) => m.clone(),
        None => {
            let mut one = vec![0.0f32; styles.len()];
            one[a.style] = 1.0;
            one
        }
    };
    let code = pair.student.code(Some(&mix), &device)?;
    let vgg = a.vgg.load(&device)?;
    let out = a.out.clone().unwrap_or_else(|| a.run.join("consistency"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;

    let size = a.size.as_deref().map(parse_size).transpose()?;
    let cameras: Vec<_> = pair
        .cameras(a.path, a.frames)?
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
    let mut counter = Counter::new("rendered", a.frames);
    let renders = PathRenders::render(&pair, cameras, code, &device, |i| {
        if !a.quiet {
            counter.done(i);
        }
    })?;
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
            vgg: &vgg,
            settings: &settings,
            quiet: true,
            keep_runs: false,
            device: &device,
        };
        let written = stylize_frames(&paths, &out.join(dir), |p: &Path| RgbImage::load(p), &each)?;
        written.iter().map(|p| RgbImage::load(p)).collect()
    };
    let mut baseline_seconds = None;
    let mut baseline = None;
    if a.baseline2d {
        let b_started = std::time::Instant::now();
        eprintln!(
            "per-view 2D baseline: {} frames, {} steps each",
            pretrained.len(),
            a.baseline_steps
        );
        let all: Vec<usize> = (0..pretrained.len()).collect();
        let frames = gatys(a.baseline_steps, a.baseline_lr, &all, "baseline2d")?;
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
        style_args.style_size,
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

    // Texture on the object, at a handful of views, against Gatys run to convergence there.
    let views = reference_views(pretrained.len(), a.reference_views);
    let r_started = std::time::Instant::now();
    eprintln!(
        "converged 2D reference: {} views, {} steps each",
        views.len(),
        a.reference_steps
    );
    let converged = gatys(a.reference_steps, REFERENCE_LR, &views, "reference2d")?;
    let reference_seconds = r_started.elapsed().as_secs_f64();
    let texture = TextureTable::score(
        &vgg,
        &PaintingFeatures::new(&vgg, &painting, style_args.style_size, &device),
        &renders,
        &views,
        &stylized,
        baseline.as_deref(),
        &converged,
        &device,
    );

    write_pairs(&out.join("pairs.jsonl"), &sets)?;
    write_views(&out.join("views.jsonl"), &sets)?;
    let (depth_error, opacity_agreement) = renders.depth_agreement();
    let mut summary = json!({
        "run": a.run,
        "pretrained_run": from,
        "painting": painting_path,
        "mix": ins_models::style_mix::normalized(styles.len(), Some(&mix))?,
        "path": a.path.unwrap_or(pair.default_path()).name(),
        "frames": renders.cameras.len(),
        "size": [w, h],
        "ranges": RANGES,
        "depth_rel_error_median": depth_error,
        "opacity_agreement": round(opacity_agreement, 4),
        "sets": sets.iter().map(set_line).collect::<Vec<_>>(),
        "texture": texture.to_json(),
        "render_seconds": round(render_seconds, 1),
        "reference2d_seconds": round(reference_seconds, 1),
        "reference2d_steps": a.reference_steps,
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
    plot_strength_consistency(
        &texture.strength_points(&sets),
        &out.join("strength_consistency.png"),
    )?;
    for s in &sets {
        println!("{}", set_line(s));
    }
    println!("{summary}");
    eprintln!(
        "wrote {}/summary.json, pairs.jsonl, views.jsonl, strength_consistency.png and the frames",
        out.display()
    );
    Ok(())
}

/// Learning rate of the converged 2D reference (pixel units): lower than the baseline's, as
/// the reference runs long enough to settle.
pub const REFERENCE_LR: f64 = 0.02;

/// `n` frames spread evenly over a path of `frames` (none past the end).
fn reference_views(frames: usize, n: usize) -> Vec<usize> {
    let n = n.clamp(1, frames.max(1));
    (0..n).map(|i| (2 * i + 1) * frames / (2 * n)).collect()
}

/// Nearest-neighbour feature distances to the painting on the object at the reference views,
/// per set and per layer, and the transfer ratios they give.
struct TextureTable {
    /// `(set, per-layer distance)`, the converged reference last.
    rows: Vec<(&'static str, [f64; 4])>,
}

impl TextureTable {
    #[allow(clippy::too_many_arguments)]
    fn score(
        vgg: &Vgg,
        painting: &PaintingFeatures,
        renders: &PathRenders,
        views: &[usize],
        stylized: &[RgbImage],
        baseline: Option<&[RgbImage]>,
        converged: &[RgbImage],
        device: &burn::prelude::Device,
    ) -> Self {
        let masks: Vec<Vec<bool>> = views
            .iter()
            .map(|&i| renders.pretrained[i].object())
            .collect();
        let pick = |frames: &[RgbImage]| -> Vec<RgbImage> {
            views.iter().map(|&i| frames[i].clone()).collect()
        };
        let pretrained: Vec<RgbImage> = views
            .iter()
            .map(|&i| renders.pretrained[i].image.clone())
            .collect();
        let d = |frames: &[RgbImage]| texture_distances(vgg, painting, frames, &masks, device);
        let mut rows = vec![
            ("pretrained", d(&pretrained)),
            ("stylized", d(&pick(stylized))),
        ];
        if let Some(b) = baseline {
            rows.push(("baseline2d", d(&pick(b))));
        }
        rows.push(("reference2d", d(converged)));
        Self { rows }
    }

    fn distances(&self, set: &str) -> Option<[f64; 4]> {
        self.rows.iter().find(|(s, _)| *s == set).map(|(_, d)| *d)
    }

    /// Per layer, the share of the way from the pretrained frames to the converged reference
    /// that `set` went.
    fn ratios(&self, set: &str) -> Option<[Option<f64>; 4]> {
        let (p, r, s) = (
            self.distances("pretrained")?,
            self.distances("reference2d")?,
            self.distances(set)?,
        );
        Some(std::array::from_fn(|l| transfer_ratio(p[l], s[l], r[l])))
    }

    /// The sets that have both a texture transfer and warp errors, for the picture (the
    /// pretrained frames at 0 by definition).
    fn strength_points(&self, sets: &[SetScores]) -> Vec<StrengthPoint> {
        sets.iter()
            .filter_map(|s| {
                let r = self.ratios(&s.set)?;
                let texture = if s.set == "pretrained" {
                    0.0
                } else {
                    TEXTURE_LAYERS.iter().filter_map(|&l| r[l]).sum::<f64>()
                        / TEXTURE_LAYERS.len() as f64
                };
                Some(StrengthPoint {
                    set: s.set.clone(),
                    texture,
                    rmse: [s.rmse[0], s.rmse[1]],
                })
            })
            .collect()
    }

    fn to_json(&self) -> serde_json::Value {
        let names = vgg_import::VggFeatures::NAMES;
        let mean = |v: [Option<f64>; 4], layers: [usize; 2]| -> Option<f64> {
            let x: Vec<f64> = layers.iter().filter_map(|&l| v[l]).collect();
            (x.len() == layers.len()).then(|| x.iter().sum::<f64>() / x.len() as f64)
        };
        let sets: Vec<serde_json::Value> = self
            .rows
            .iter()
            .map(|(set, d)| {
                let mut line = json!({"set": set});
                for (l, name) in names.iter().enumerate() {
                    line[format!("nn_{name}")] = round(d[l], 4).into();
                }
                if let Some(r) = self.ratios(set) {
                    for (l, name) in names.iter().enumerate() {
                        line[format!("transfer_{name}")] = r[l].map(|v| round(v, 3)).into();
                    }
                    line["palette_transfer"] = mean(r, PALETTE_LAYERS).map(|v| round(v, 3)).into();
                    line["texture_transfer"] = mean(r, TEXTURE_LAYERS).map(|v| round(v, 3)).into();
                }
                line
            })
            .collect();
        json!({
            "measure": "mean over object positions of 1 - best cosine similarity to the painting's VGG features",
            "sets": sets,
        })
    }
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
