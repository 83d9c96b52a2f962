//! `ins-cli eval consistency`: how consistent a stylized NeRF or IDR run is across views,
//! against the per-view 2D baseline and the unstylized floor, with style and content distances
//! per view; and how much of the painting's texture reached the object, against Gatys run to
//! convergence on a few of the same views. The evaluation itself is
//! `ins_models::consistency::evaluate`.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use ins_models::consistency::evaluate::{
    BASELINE_LR, BASELINE_STEPS, FRAMES, REFERENCE_STEPS, REFERENCE_VIEWS,
};
use ins_models::consistency::{ConsistencyOptions, Progress, StylizedPair, evaluate};
use ins_scene::paths::PathKind;

use crate::common::{DeviceArgs, VggArgs, parse_size};
use crate::counter::Counter;

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
    #[arg(long, default_value_t = FRAMES)]
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
    /// Gatys' method run to convergence (0: no texture measure).
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

impl EvalConsistency {
    /// The evaluation's options.
    fn options(&self) -> Result<ConsistencyOptions> {
        Ok(ConsistencyOptions {
            path: self.path,
            frames: self.frames,
            size: self.size.as_deref().map(parse_size).transpose()?,
            style: self.style,
            mix: self.mix.clone(),
            baseline2d: self.baseline2d,
            baseline_steps: self.baseline_steps,
            baseline_lr: self.baseline_lr,
            reference_views: self.reference_views,
            reference_steps: self.reference_steps,
            out: self.out.clone(),
        })
    }
}

/// Stage lines on stderr; the rendering count unless `--quiet`.
pub struct CliProgress {
    quiet: bool,
    counter: Option<Counter>,
}

impl CliProgress {
    /// Progress that shows the rendering count unless `quiet`.
    pub fn new(quiet: bool) -> Self {
        Self {
            quiet,
            counter: None,
        }
    }
}

impl Progress for CliProgress {
    fn note(&mut self, message: &str) {
        eprintln!("{message}");
    }

    fn rendered(&mut self, done: usize, total: usize) {
        if !self.quiet {
            self.counter
                .get_or_insert_with(|| Counter::new("rendered", total))
                .done(done);
        }
    }
}

pub fn run(a: EvalConsistency) -> Result<()> {
    let options = a.options()?;
    let backend = a.device.backend.resolve();
    let device = backend.try_device()?;
    let pair = StylizedPair::load(&a.run, &device)?;
    pair.painting(options.style)?;
    let vgg = a.vgg.load(&device)?;
    eprintln!("evaluating {} on {backend}", a.run.display());
    let mut progress = CliProgress::new(a.quiet);
    let e = evaluate(&pair, &options, &vgg, &device, &mut progress)?;
    for line in &e.sets {
        println!("{line}");
    }
    println!("{}", e.summary);
    eprintln!(
        "wrote {}/summary.json, pairs.jsonl, views.jsonl, strength_consistency.png and the frames",
        e.out.display()
    );
    Ok(())
}
