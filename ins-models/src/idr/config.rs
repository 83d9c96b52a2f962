//! The configuration of an IDR run: `ins-cli train idr` flags and the run's `config.json`.

use serde::{Deserialize, Serialize};

use super::eval::ViewOptions;
use super::model::{DEFAULT_GRID_TABLE, IdrArch, SdfKind, SdfRenderer};
use super::volume::{UPSAMPLE_ROUNDS, VolumeSampling, one_round};
use crate::run::args::{RunKind, ScheduleArgs, SourceArgs, StyleArgs, StylizerArgs};
use ins_core::render::sphere_tracing::TraceOptions;

/// Weight of the volume renderer's mask term (see `--mask-weight`).
pub const VOLUME_MASK_WEIGHT: f64 = 1.0;

/// Share of the volume renderer's rays drawn inside the masks (see `--mask-rays`).
pub const VOLUME_MASK_RAYS: f32 = 0.5;

/// Weight of the volume renderer's smoothness term (see `--curvature-weight`). On scan37 (2500
/// steps) 0.1 took the scissors' ghost copies out of the brick's surface at 18.81 dB held out
/// (18.69 without the term), where 0.5 smoothed more and cost a decibel (17.67); on the
/// notched block 0.1 took the mesh's normals from 35° to 27° off the truth, 0.5 to 22°, and
/// 2 filled its hollow corner again.
pub const VOLUME_CURVATURE_WEIGHT: f64 = 0.1;

fn no_curvature() -> Option<f64> {
    Some(0.0)
}

/// Finest resolution of the volume renderer's appearance grid (see `--color-grid`).
pub const VOLUME_COLOR_GRID: u32 = 2047;

fn no_color_grid() -> Option<u32> {
    Some(0)
}

/// Everything that defines an IDR run, pretraining (`--scene`) or stylization (`--from`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct IdrRunConfig {
    /// Scene or base run.
    #[command(flatten)]
    #[serde(flatten)]
    pub source: SourceArgs,
    /// Steps, learning rate, seed, checkpoints.
    #[command(flatten)]
    #[serde(flatten)]
    pub schedule: ScheduleArgs,
    /// Paintings and the perceptual loss.
    #[command(flatten)]
    #[serde(flatten)]
    pub style: StyleArgs,
    /// SIM size.
    #[command(flatten)]
    #[serde(flatten)]
    pub stylizer: StylizerArgs,
    /// SDF network: grid (fast, default) or mlp (IDR's 8×512).
    #[arg(long, default_value = "grid")]
    pub sdf: SdfKind,
    /// Hold out every K-th view for evaluation (0: train on all views).
    #[arg(long, default_value_t = 0)]
    pub holdout: usize,
    /// Train without masks (every pixel counts as the object; no mask loss): a weaker result.
    #[arg(long)]
    pub no_mask: bool,
    /// How pretraining renders the SDF: volume (NeuS: every sample along a ray weighted by a
    /// learnable sharpness, so concavities open and colour averages over the surface's band)
    /// or surface (IDR: the sphere-traced first hit, faster a step but blind to hollows the
    /// masks do not show). Sphere tracing still draws the normals and depth, and meshes come
    /// from the SDF's zero level set either way. On scan37 in about 10 minutes on 2 cores the
    /// volume's defaults reached 20.94 dB held out (IoU 0.984) where the surface's reached
    /// 19.98 (0.990).
    /// (A run folder written before the volume renderer existed is a surface run.)
    #[arg(long, default_value = "volume")]
    #[serde(default)]
    pub renderer: SdfRenderer,
    /// Rays per pretraining step (0: the renderer's own, 2048 for the surface, 512 for the
    /// volume, whose every ray costs its samples).
    #[arg(long, default_value_t = 0)]
    pub rays: usize,
    /// Volume renderer: stratified samples per ray inside the unit sphere where the SDF alone
    /// is looked at, to find the surface.
    #[arg(long, default_value_t = 64)]
    pub samples: usize,
    /// Volume renderer: of those, how many the colour and gradient pass keeps (evenly strided).
    #[arg(long, default_value_t = 8)]
    pub kept_samples: usize,
    /// Volume renderer: samples per ray drawn near the surface, where the colour and gradient
    /// pass spends most of its time.
    #[arg(long, default_value_t = 16)]
    pub fine_samples: usize,
    /// Volume renderer: rounds of drawing the fine samples (NeuS's up-sampling). Each round but
    /// the last looks at the SDF alone at its samples, and the next draws among all samples so
    /// far at twice the sharpness, so the last round's (the fine pass's) sit in the surface's
    /// band instead of across a coarse section. On scan37, 2 rounds gave 21.64 dB held out
    /// against 21.29 with 1 (IoU 0.989 both) for a step no longer than the noise.
    /// (A run folder written before the rounds existed drew once.)
    #[arg(long, default_value_t = UPSAMPLE_ROUNDS)]
    #[serde(default = "one_round")]
    pub upsample_rounds: usize,
    /// Share of each pretraining batch drawn from inside the masks, the rest uniformly over
    /// the images (default: the surface renderer 0, as IDR; the volume renderer 0.5). About 60 %
    /// of scan37's uniform rays miss the object: they teach the silhouette and nothing of the
    /// colour. For the volume, whose steps are few, 0.5 gave 20.57 dB held out after 3700 steps
    /// against 19.23 (IoU 0.983 against 0.986); for the surface, 17.49 dB after 3000 steps
    /// against 17.68 (docs/measurements.md). The mask term weighs each ray by how much rarer
    /// uniform rays would draw its pixel, so the silhouette is set as uniform rays would set it
    /// (unweighted, scan37's swelled by a pixel: IoU 0.986 / 0.987 over seeds 0 / 1 against
    /// 0.989 / 0.990 weighted, 0.2 dB more inside the mask).
    #[arg(long)]
    pub mask_rays: Option<f32>,
    /// Pretraining: the learning rate falls exponentially to this fraction of `--lr` by the
    /// last step. On scan37 at 400×300 over 4000 steps, 0.1 gave 18.37 dB held-out masked PSNR
    /// and 0.01 gave 17.56.
    #[arg(long, default_value_t = 0.1)]
    pub lr_decay: f64,
    /// Radius of the initial sphere.
    #[arg(long, default_value_t = 0.6)]
    pub init_radius: f64,
    /// `grid` SDF: finest resolution of the hash encoding over the unit sphere's cube (finer
    /// levels fit finer texture but leave the surface, and so its normals, noisier). On scan37
    /// at 200×150 (held-out masked PSNR after 3000 steps, colour width 128): 256 → 18.95 dB,
    /// 512 → 19.87; at 400×300 a 2047 level (2^19 table) gave 15.81 dB where 512 gave 17.68.
    #[arg(long, default_value_t = 512)]
    pub grid_max_resolution: u32,
    /// `grid` SDF: log2 of the hash table's entries per level (up to 19). Levels finer than
    /// the table (from about 50 cells across at 2^17) share entries between cells.
    #[arg(long, default_value_t = DEFAULT_GRID_TABLE)]
    pub grid_table: u32,
    /// Width of the colour network's hidden layers (`grid` SDF). On scan37 at 200×150, 128 with a
    /// 512 grid gave 19.87 dB held-out masked PSNR where 64 with a 1024 grid gave 18.23; at
    /// 400×300 with the volume's defaults 256 gave 21.43 dB against 21.40, a step 13 % longer.
    #[arg(long, default_value_t = 128)]
    pub color_width: usize,
    /// Finest resolution of an appearance hash grid in the colour network (0: none; default:
    /// the volume renderer 2047, the surface renderer none): texture finer than the SDF's grid,
    /// which has to stay coarse for smooth normals, can hold. Its 12.2 M parameters make a run
    /// folder about 350 MB instead of 80, the peak memory about 0.9 GB instead of 0.5 and a
    /// volume step about an eighth longer. On scan37 the volume's defaults gained 0.5 dB held
    /// out with it (21.47 / 21.35 dB against 20.82 / 20.77 over seeds 0 / 1, IoU the same or
    /// better), and a stylization blends the grid's features with the style
    /// (docs/measurements.md). (A run folder written before it was a default says what it had.)
    #[arg(long)]
    #[serde(default = "no_color_grid")]
    pub color_grid: Option<u32>,
    /// Whether a stylization's AM blends the appearance grid's features with the SDF's, not
    /// only the SDF's: set when stylizing a base with a grid (since the thirty-fourth session;
    /// the grid's photo texture reached the colour untouched before, and a folder from then
    /// reads as not).
    #[arg(skip)]
    pub stylize_color_grid: bool,
    /// Weight of the mask loss (0: the renderer's own: IDR's 100 on its sharpening
    /// closest-approach term; 1 on the volume's opacity cross-entropy, where NeuS's 0.1 left a
    /// blurred band outside scan37's silhouette, IoU 0.89 after 1000 steps).
    #[arg(long, default_value_t = 0.0)]
    pub mask_weight: f64,
    /// Weight of the eikonal loss (IDR: 0.1).
    #[arg(long, default_value_t = 0.1)]
    pub eikonal_weight: f64,
    /// Weight of the smoothness term (`--renderer volume`, default 0.1; 0: none): the squared
    /// change of the SDF's gradient over a small random step at samples near the surface,
    /// which keeps a hash-grid surface from bending to explain texture.
    /// (A run folder written before the term existed had none: it resumes without one.)
    #[arg(long)]
    #[serde(default = "no_curvature")]
    pub curvature_weight: Option<f64>,
    /// Random points of the unit sphere's box per pretraining step where the eikonal loss
    /// holds the field to a distance (default: the surface renderer 2048, IDR's as many as
    /// rays; the volume renderer 0, its samples already cover each ray). Each costs a
    /// forward-mode gradient and its backward; the surface or volume samples count too.
    #[arg(long)]
    pub eikonal_points: Option<usize>,
    /// Steps between evaluations on held-out views (0: only at the end; default: the surface
    /// renderer every 2000, the volume renderer only at the end). Each renders every held-out
    /// view in full and draws its picture (scan37's seven at 400×300 on 2 cores: about 20 s
    /// sphere-traced, about 100 s as a volume).
    #[arg(long)]
    pub eval_every: Option<usize>,
    /// Stylization: SDF learning rate as a fraction of the others' (the paper: 1e-11, in
    /// effect frozen; 0 freezes the surface outright).
    #[arg(long, default_value_t = 0.0)]
    pub sdf_lr_ratio: f64,
}

crate::run::args::scene_run_config!(IdrRunConfig, "a surface");

impl IdrRunConfig {
    /// The model sizes.
    pub fn arch(&self) -> IdrArch {
        IdrArch {
            sdf: self.sdf,
            radius: self.init_radius,
            grid_max_resolution: self.grid_max_resolution,
            grid_table: self.grid_table,
            color_width: self.color_width,
            color_grid: self.color_grid_for(),
            renderer: self.renderer,
            background: self.no_mask && self.renderer == SdfRenderer::Volume,
        }
    }

    /// Rays per pretraining step.
    pub fn rays_for(&self) -> usize {
        match (self.rays, self.renderer) {
            (0, SdfRenderer::Surface) => 2048,
            (0, SdfRenderer::Volume) => 512,
            (n, _) => n,
        }
    }

    /// Share of the rays drawn inside the masks.
    pub fn mask_rays_for(&self) -> f32 {
        match (self.mask_rays, self.renderer) {
            (Some(share), _) => share,
            (None, SdfRenderer::Surface) => 0.0,
            (None, SdfRenderer::Volume) => VOLUME_MASK_RAYS,
        }
    }

    /// Weight of the mask term.
    pub fn mask_weight_for(&self) -> f64 {
        match (self.mask_weight, self.renderer) {
            (w, _) if w > 0.0 => w,
            (_, SdfRenderer::Surface) => 100.0,
            (_, SdfRenderer::Volume) => VOLUME_MASK_WEIGHT,
        }
    }

    /// Finest resolution of the colour network's appearance grid (0: none).
    pub fn color_grid_for(&self) -> u32 {
        match (self.color_grid, self.renderer) {
            (Some(r), _) => r,
            (None, SdfRenderer::Surface) => 0,
            (None, SdfRenderer::Volume) => VOLUME_COLOR_GRID,
        }
    }

    /// Weight of the smoothness term.
    pub fn curvature_weight_for(&self) -> f64 {
        match (self.curvature_weight, self.renderer) {
            (Some(w), _) => w,
            (None, SdfRenderer::Surface) => 0.0,
            (None, SdfRenderer::Volume) => VOLUME_CURVATURE_WEIGHT,
        }
    }

    /// Random eikonal points per pretraining step.
    pub fn eikonal_points_for(&self) -> usize {
        match (self.eikonal_points, self.renderer) {
            (Some(n), _) => n,
            (None, SdfRenderer::Surface) => 2048,
            (None, SdfRenderer::Volume) => 0,
        }
    }

    /// Steps between held-out evaluations (0: only at the end).
    pub fn eval_every_for(&self) -> usize {
        match (self.eval_every, self.renderer) {
            (Some(n), _) => n,
            (None, SdfRenderer::Surface) => 2000,
            (None, SdfRenderer::Volume) => 0,
        }
    }

    /// The volume renderer's samples.
    pub fn volume_sampling(&self) -> VolumeSampling {
        VolumeSampling {
            coarse: self.samples,
            kept: self.kept_samples,
            fine: self.fine_samples,
            rounds: self.upsample_rounds,
            ..VolumeSampling::default()
        }
    }

    /// How the run's views are rendered: the default tracer and the run's volume samples.
    pub fn view_options(&self) -> ViewOptions {
        ViewOptions {
            trace: TraceOptions::default(),
            sampling: self.volume_sampling(),
        }
    }

    /// Steps to run.
    pub fn steps_for(&self, kind: RunKind) -> usize {
        match (self.schedule.steps, kind) {
            // A volume step of 512 rays, half inside the masks, costs about two surface steps of
            // 2048 (24 samples a ray with their gradients, colours where seen): about 100 ms on
            // scan37 (400×300, 2 cores) against the surface's 12000 steps in 621 s.
            // Without masks each ray also samples the field beyond the sphere (32 more): the
            // 2500 steps its figures were measured at (about 13 minutes on a Xeon).
            (0, RunKind::Pretrain) if self.renderer == SdfRenderer::Volume && self.no_mask => 2500,
            (0, RunKind::Pretrain) if self.renderer == SdfRenderer::Volume => 6000,
            (0, RunKind::Pretrain) => 12000,
            (0, RunKind::Stylize) => 400,
            (n, _) => n,
        }
    }

    /// Learning rate.
    pub fn lr_for(&self, kind: RunKind) -> f64 {
        if self.schedule.lr > 0.0 {
            return self.schedule.lr;
        }
        match (kind, self.sdf) {
            (RunKind::Pretrain, SdfKind::Grid) => 5e-3,
            (RunKind::Pretrain, SdfKind::Mlp) => 1e-4,
            // On scan37 at 1e-3 the style loss had barely moved after 200 steps; at 5e-3 it
            // fell 4.6× over the 400 (1.7e6 to 3.7e5, the mean of the last 40).
            (RunKind::Stylize, SdfKind::Grid) => 5e-3,
            (RunKind::Stylize, SdfKind::Mlp) => 1e-3,
        }
    }

    /// SIM width (0 in the config: 64).
    pub fn sim_width_for(&self) -> usize {
        if self.stylizer.sim_width > 0 {
            self.stylizer.sim_width
        } else {
            64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh run renders a volume, half its rays inside the masks; a run folder written
    /// before the volume renderer existed (no `renderer` or `mask_rays` in its `config.json`)
    /// reads back as the surface run it was, with IDR's uniform rays.
    #[test]
    fn new_runs_are_volumes_and_old_run_folders_stay_surfaces() {
        let fresh = IdrRunConfig::default();
        assert_eq!(fresh.renderer, SdfRenderer::Volume);
        assert_eq!(fresh.mask_rays_for(), VOLUME_MASK_RAYS);
        assert_eq!(fresh.rays_for(), 512);
        assert_eq!(fresh.steps_for(RunKind::Pretrain), 6000);
        assert_eq!(fresh.arch().color_grid, VOLUME_COLOR_GRID);
        assert_eq!(fresh.arch().grid_table, DEFAULT_GRID_TABLE);
        assert_eq!(fresh.volume_sampling().rounds, UPSAMPLE_ROUNDS);
        let surface = IdrRunConfig {
            renderer: SdfRenderer::Surface,
            ..IdrRunConfig::default()
        };
        assert_eq!(surface.arch().color_grid, 0);
        let unmasked = IdrRunConfig {
            no_mask: true,
            ..IdrRunConfig::default()
        };
        assert_eq!(unmasked.steps_for(RunKind::Pretrain), 2500);

        let old: IdrRunConfig =
            serde_json::from_str(r#"{"scene": "/scan37", "holdout": 8, "mask_weight": 100.0}"#)
                .unwrap();
        assert_eq!(old.renderer, SdfRenderer::Surface);
        assert_eq!(old.mask_rays_for(), 0.0);
        assert_eq!(old.rays_for(), 2048);
        assert_eq!(old.steps_for(RunKind::Pretrain), 12000);
        assert_eq!(old.holdout, 8);
        assert_eq!(old.arch().color_grid, 0);
        assert_eq!(old.arch().grid_table, DEFAULT_GRID_TABLE);
        // A stylized folder from before the AM blended the appearance grid reads as not.
        assert!(!old.stylize_color_grid);
        // A volume run folder from before the appearance grid was its default kept none.
        let volume: IdrRunConfig =
            serde_json::from_str(r#"{"scene": "/scan37", "renderer": "volume", "color_grid": 0}"#)
                .unwrap();
        assert_eq!(volume.arch().color_grid, 0);
        let without: IdrRunConfig =
            serde_json::from_str(r#"{"scene": "/scan37", "renderer": "volume"}"#).unwrap();
        assert_eq!(without.arch().color_grid, 0);
        // ...and drew its fine samples in one round.
        assert_eq!(without.volume_sampling().rounds, 1);
        assert_eq!(without.view_options().sampling.rounds, 1);
    }

    /// Views are rendered with the samples the run trained with, and a run stylizing a base
    /// renders the base's frozen surface with the base's samples, not the defaults.
    #[test]
    fn views_render_with_the_samples_the_surface_was_trained_with() {
        use crate::run::Variant;
        let base = IdrRunConfig {
            samples: 32,
            kept_samples: 4,
            fine_samples: 24,
            upsample_rounds: 3,
            ..IdrRunConfig::default()
        };
        let sampling = base.view_options().sampling;
        assert_eq!(
            (
                sampling.coarse,
                sampling.kept,
                sampling.fine,
                sampling.rounds
            ),
            (32, 4, 24, 3)
        );
        let mut stylized = IdrRunConfig::default();
        super::super::run::Idr::inherit(&mut stylized, &base, std::path::Path::new("/base"))
            .unwrap();
        assert_eq!(stylized.view_options(), base.view_options());
    }
}
