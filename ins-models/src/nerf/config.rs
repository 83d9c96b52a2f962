//! The configuration of a NeRF run: `ins-cli train nerf` flags and the run's `config.json`.

use ins_core::modules::field::CimKind;
use serde::{Deserialize, Serialize};

use super::model::NerfArch;
use crate::run::args::{RunKind, ScheduleArgs, SourceArgs, StyleArgs, StylizerArgs};

/// Everything that defines a NeRF run, pretraining (`--scene`) or stylization (`--from`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct NerfRunConfig {
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
    /// Content module: grid (fast, default) or mlp (the paper's NeRF, slow on a CPU).
    #[arg(long, default_value = "grid")]
    pub cim: CimKind,
    /// Grid: fine samples per step the ray count adapts to.
    #[arg(long, default_value_t = 1 << 17)]
    pub target_samples: usize,
    /// MLP: rays per step.
    #[arg(long, default_value_t = 1024)]
    pub rays: usize,
    /// MLP: stratified (coarse) samples per ray.
    #[arg(long, default_value_t = 64)]
    pub coarse_samples: usize,
    /// MLP: importance (fine) samples per ray.
    #[arg(long, default_value_t = 128)]
    pub fine_samples: usize,
    /// Grid: log2 of the hash table size per level.
    #[arg(long, default_value_t = 17)]
    pub log2_table: u32,
    /// Grid: finest resolution.
    #[arg(long, default_value_t = 1024)]
    pub max_resolution: u32,
    /// Occupancy grid cells per axis.
    #[arg(long, default_value_t = 128)]
    pub occupancy_resolution: u32,
    /// Steps between occupancy grid refreshes.
    #[arg(long, default_value_t = 16)]
    pub occupancy_every: usize,
    /// Cap of samples per ray when marching.
    #[arg(long, default_value_t = 512)]
    pub max_samples_per_ray: usize,
    /// Steps between evaluations on held-out views (0: only at the end).
    #[arg(long, default_value_t = 500)]
    pub eval_every: usize,
    /// Held-out views rendered per evaluation during training.
    #[arg(long, default_value_t = 4)]
    pub eval_views: usize,
    /// Stylization: weight of the geometry loss mean|σ_teacher − σ|. Large because the style
    /// term it competes with is ~1e6 (Gram distances in VGG's units): at 1 the density drifted
    /// (lego: mean |Δσ| 2.0, holes in the depth), at 1e5 it stays (2e-4) and the style loss
    /// falls as far.
    #[arg(long, default_value_t = 1e5)]
    pub geometry_weight: f64,
    /// Stylization: also stylize the density (the paper's choice); off (the default) keeps the
    /// pretrained density. On lego freezing it drew the same strokes (texture transfer 1.04
    /// against 1.07) with the depth exact; on a forward-facing capture (fern) a stylized density
    /// followed the strokes, broke the depth and erased the fern (docs/measurements.md).
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set)]
    pub stylize_density: bool,
    /// Stylization: rays per chunk of deferred back-propagation (ARF's). A patch with more
    /// rays than this is rendered once without a graph, the loss's gradient taken at its
    /// pixels, then rendered again chunk by chunk, each chunk back-propagating its share: a
    /// full-view patch (`--patch 200 --stride 1`) then costs a chunk's memory. The default
    /// patch (64², 4096 rays) runs directly.
    #[arg(long, default_value_t = 4096)]
    pub backprop_chunk: usize,
    /// Pretraining a capture (COLMAP, transforms.json): after 30 % of the steps, the training
    /// photos that fit the field 6 dB or more below the median (posed wrongly by structure
    /// from motion or a phone's tracking) are named and left out; `false` keeps every photo.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub drop_misposed: bool,
}

crate::run::args::scene_run_config!(NerfRunConfig, "a NeRF");

impl NerfRunConfig {
    /// The model sizes.
    pub fn arch(&self) -> NerfArch {
        NerfArch {
            cim: self.cim,
            log2_table: self.log2_table,
            max_resolution: self.max_resolution,
        }
    }

    /// Steps to pretrain on a scene: forward-facing ones (LLFF, forward captures) get more, as
    /// their held-out views keep improving long after a 360° scene's have settled (fern, grid:
    /// 21.9 dB at 1000 steps; 23.6 / 24.5 at steps 2000 / 4000 of a 4000-step run). 2000 keeps
    /// a capture's pretraining within about 15 minutes on two cores; `--steps 4000` buys the
    /// last decibel.
    pub fn pretrain_steps_for(&self, forward_facing: bool) -> usize {
        match (self.schedule.steps, self.cim, forward_facing) {
            (0, CimKind::Grid, true) => 2000,
            _ => self.steps_for(RunKind::Pretrain),
        }
    }

    /// Steps to run (the default depends on the kind and the content module).
    pub fn steps_for(&self, kind: RunKind) -> usize {
        if self.schedule.steps > 0 {
            return self.schedule.steps;
        }
        match (kind, self.cim) {
            (RunKind::Pretrain, CimKind::Grid) => 1000,
            (RunKind::Pretrain, CimKind::Mlp) => 200_000,
            (RunKind::Stylize, CimKind::Grid) => 600,
            (RunKind::Stylize, CimKind::Mlp) => 50_000,
        }
    }

    /// Learning rate (the default depends on the kind and the content module).
    pub fn lr_for(&self, kind: RunKind) -> f64 {
        if self.schedule.lr > 0.0 {
            return self.schedule.lr;
        }
        match (kind, self.cim) {
            (RunKind::Pretrain, CimKind::Grid) => 1e-2,
            (RunKind::Pretrain, CimKind::Mlp) => 5e-4,
            (RunKind::Stylize, CimKind::Grid) => 1e-3,
            (RunKind::Stylize, CimKind::Mlp) => 1e-4,
        }
    }

    /// SIM width.
    pub fn sim_width_for(&self) -> usize {
        if self.stylizer.sim_width > 0 {
            self.stylizer.sim_width
        } else if self.cim == CimKind::Grid {
            64
        } else {
            256
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(steps: usize, cim: CimKind) -> NerfRunConfig {
        let mut cfg = NerfRunConfig {
            cim,
            ..Default::default()
        };
        cfg.schedule.steps = steps;
        cfg
    }

    #[test]
    fn forward_facing_scenes_pretrain_longer_unless_steps_are_given() {
        let grid = config(0, CimKind::Grid);
        assert_eq!(grid.pretrain_steps_for(true), 2000);
        assert_eq!(grid.pretrain_steps_for(false), 1000);
        assert_eq!(config(0, CimKind::Mlp).pretrain_steps_for(true), 200_000);
        assert_eq!(config(250, CimKind::Grid).pretrain_steps_for(true), 250);
    }
}
