//! The argument groups every variant's configuration is made of. Each group is both clap flags
//! (flattened into `ins-cli train <variant>`) and JSON fields (flattened into the run's
//! `config.json`, so a run folder's config stays one flat object).
//!
//! A value of 0 in a numeric field means "the variant's default" where the doc says so; the
//! run resolves it before writing `config.json`, which therefore holds the values that ran.

use std::path::PathBuf;

use anyhow::{Result, bail};
use ins_core::loss::StyleLoss;
use ins_core::modules::style_position::StylePositionConfig;
use serde::{Deserialize, Serialize};

/// Whether a run pretrains on a scene or stylizes a pretrained run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunKind {
    /// `--scene`: learn the scene (and, for SIREN, stylize it in the same run).
    Pretrain,
    /// `--from RUN --style IMG`: stylize a pretrained run.
    Stylize,
}

/// Where a scene run starts: a scene folder to pretrain on, or a pretrained run to stylize.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct SourceArgs {
    /// Scene folder to pretrain on (NeRF: Blender, LLFF or DTU; IDR: DTU/IDR with masks).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Pretrained run to stylize (its scene, model and scene settings are reused).
    #[arg(long)]
    pub from: Option<PathBuf>,
    /// Image downscale factor (0: the whole factor that brings the longer side nearest 400 px).
    #[arg(long, default_value_t = 0)]
    pub downscale: u32,
    /// COLMAP workspaces: the photos' folder when it is not `images/` beside the model.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
}

impl Default for SourceArgs {
    fn default() -> Self {
        crate::config::clap_defaults()
    }
}

impl SourceArgs {
    /// Which kind of run `self` and `styles` describe; an error when both or neither of
    /// `--scene` and `--from` are given, or styles come without `--from`. `what` names the
    /// variant's subject in the messages ("a NeRF", "a surface").
    pub fn kind(&self, styles: &[PathBuf], what: &str) -> Result<RunKind> {
        match (&self.scene, &self.from) {
            (Some(_), None) if styles.is_empty() => Ok(RunKind::Pretrain),
            (Some(_), None) => bail!(
                "--style needs --from RUN (stylize a pretrained run); pretrain with --scene first"
            ),
            (None, Some(_)) if !styles.is_empty() => Ok(RunKind::Stylize),
            (None, Some(_)) => bail!("stylizing (--from) needs at least one --style image"),
            (Some(_), Some(_)) => {
                bail!("give either --scene (pretrain) or --from (stylize), not both")
            }
            (None, None) => bail!(
                "give --scene DIR to pretrain {what}, or --from RUN --style IMG to stylize one"
            ),
        }
    }
}

/// How long and how fast a scene run trains, and how it is seeded and checkpointed.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct ScheduleArgs {
    /// Training steps (0: the variant's default; NeRF with the grid 1000 pretraining, 2000 on
    /// forward-facing scenes (LLFF, forward captures), 600 stylizing, with the mlp 200000 /
    /// 50000; IDR 12000 / 400).
    #[arg(long, default_value_t = 0)]
    pub steps: usize,
    /// Adam learning rate (0: the variant's default; NeRF grid 1e-2 pretraining, 1e-3
    /// stylizing, mlp 5e-4 / 1e-4; IDR grid 5e-3 / 5e-3, mlp 1e-4 / 1e-3).
    #[arg(long, default_value_t = 0.0)]
    pub lr: f64,
    /// Seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Steps between checkpoints.
    #[arg(long, default_value_t = 500)]
    pub checkpoint_every: usize,
}

impl Default for ScheduleArgs {
    fn default() -> Self {
        crate::config::clap_defaults()
    }
}

/// The paintings and the perceptual loss on strided patches: what stylization needs.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct StyleArgs {
    /// Style image; repeat for a conditional multi-style model (one-hot codes in this order).
    #[arg(long = "style")]
    pub styles: Vec<PathBuf>,
    /// Longer side of the style images for their Gram targets (0: 128 for SIREN, 256 for NeRF
    /// and IDR).
    #[arg(long, default_value_t = 0)]
    pub style_size: usize,
    /// How the paintings' style is matched: gram (Gatys' Gram matrices, the paper's), nnfm
    /// (ARF's nearest-neighbour feature matching) or mean-std (AdaIN's channel statistics).
    /// Default: nnfm for NeRF and IDR (it draws the painting's strokes on the object where
    /// Gram carried mostly its palette, docs/measurements.md), gram for SIREN.
    #[arg(long)]
    #[serde(default = "legacy_style_loss")]
    pub style_loss: Option<StyleLoss>,
    /// With nnfm: each place of a render may only take painting features within this cosine
    /// of the best match of the photo's feature there, so strokes follow what the photo shows
    /// (0: a style swap, the painting's feature nearest the photo's; 2: plain NNFM, whose
    /// matches follow the render and can paint a real photo over).
    #[arg(long)]
    #[serde(default = "legacy_match_radius")]
    pub match_radius: Option<f32>,
    /// With nnfm: another radius for the texture layers (relu3_3, relu4_3), the strokes'
    /// scale, while --match-radius holds at the palette layers (relu1_2, relu2_2), the
    /// colours and edges that keep the objects readable. Default: 0.4 where --match-radius is
    /// left at its default, else the same as --match-radius.
    #[arg(long)]
    #[serde(default)]
    pub texture_match_radius: Option<f32>,
    /// Style loss weight (default: per style loss and VGG preprocessing).
    #[arg(long)]
    pub style_weight: Option<f64>,
    /// Content loss weight (default: per VGG preprocessing).
    #[arg(long)]
    pub content_weight: Option<f64>,
    /// Recolour the photos into each painting's palette (mean and covariance of its colours)
    /// before taking their content features (ARF's colour transfer).
    #[arg(long)]
    #[serde(default)]
    pub color_transfer: bool,
    /// Rays (or pixels) per side of a stylization patch (0: 128 for SIREN, 64 for NeRF and IDR).
    #[arg(long, default_value_t = 0)]
    pub patch: usize,
    /// Pixels between patch rays (0: the variant's rule, see `PatchSpec::spanning`).
    #[arg(long, default_value_t = 0)]
    pub stride: usize,
}

/// What a run config written before `style_loss` existed ran: Gram. Read as such (not as
/// "unset"), so that resolving the variant's defaults cannot change an old run on `--resume`.
fn legacy_style_loss() -> Option<StyleLoss> {
    Some(StyleLoss::Gram)
}

/// What a run config written before `match_radius` existed ran: unguided NNFM (a radius of 2,
/// the whole cosine range), for the same reason.
fn legacy_match_radius() -> Option<f32> {
    Some(2.0)
}

impl Default for StyleArgs {
    fn default() -> Self {
        crate::config::clap_defaults()
    }
}

impl StyleArgs {
    /// The style loss that ran: a run folder written before the choice existed used Gram.
    pub fn loss(&self) -> StyleLoss {
        self.style_loss.unwrap_or(StyleLoss::Gram)
    }

    /// Fills the fields left at 0 (or unset) with a variant's defaults; NNFM is guided by the
    /// photo within [`DEFAULT_MATCH_RADIUS`], and within [`DEFAULT_TEXTURE_MATCH_RADIUS`] at
    /// the texture layers, unless told otherwise.
    ///
    /// The texture radius is filled only together with the palette's: a radius given alone
    /// holds at every layer, and a saved run (whose palette radius is always set) resumes with
    /// the radii it ran, also one written before the texture radius existed.
    pub fn resolve(&mut self, patch: usize, style_size: usize, style_loss: StyleLoss) {
        self.style_loss.get_or_insert(style_loss);
        if self.loss() == StyleLoss::Nnfm && self.match_radius.is_none() {
            self.match_radius = Some(DEFAULT_MATCH_RADIUS);
            self.texture_match_radius
                .get_or_insert(DEFAULT_TEXTURE_MATCH_RADIUS);
        }
        if self.patch == 0 {
            self.patch = patch;
        }
        if self.style_size == 0 {
            self.style_size = style_size;
        }
    }
}

/// How far (in cosine) from the photo's own best match NNFM may look for a position's match,
/// by default. Unguided, NNFM painted real photos over or left them; guided, the strokes follow
/// what the photo shows, more of the painting the wider the radius. On DTU scan37 with *The
/// Starry Night*, texture transfer 0.30 / 0.63 / 0.88 / 1.09 at 0.05 / 0.15 / 0.2 / 0.3 and
/// 1.21 unguided (along the arc its photos cover), the objects readable up to 0.2 and gone
/// unguided (docs/measurements.md, "scan37 measured on the side its photos saw").
pub const DEFAULT_MATCH_RADIUS: f32 = 0.2;

/// The default radius at the texture layers (relu3_3, relu4_3), where the strokes' scale lives:
/// wider than the palette's, so more of the painting's texture lands while the colours and
/// edges that keep the objects readable stay guided. Against one radius of 0.2, texture
/// transfer rose on all five scene × painting pairs measured (scan37 × Starry Night 0.88 →
/// 1.01, lego × Starry Night / Great Wave / Scream 0.91 / 1.10 / 0.73 → 0.96 / 1.19 / 0.74,
/// fern 1.23 → 1.36) with the palette and the pictures kept (docs/measurements.md).
pub const DEFAULT_TEXTURE_MATCH_RADIUS: f32 = 0.4;

/// The size of the SIM a scene run adds when it stylizes.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, clap::Args)]
#[serde(default)]
pub struct StylizerArgs {
    /// Stylization: SIM width (0: the variant's default; NeRF 64 with the grid, 256 with the
    /// mlp; IDR 64).
    #[arg(long, default_value_t = 0)]
    pub sim_width: usize,
    /// Stylization: octaves of the position encoding fed to the SIM.
    #[arg(long, default_value_t = 4)]
    pub position_freqs: usize,
    /// Stylization: finest resolution of the SIM's own texture hash grid over the scene's box
    /// (0: none, the SIM sees only the octaves). The octaves alone cannot draw strokes at a
    /// pixel's scale; a run folder written before the grid existed has none.
    #[arg(long, default_value_t = 256)]
    #[serde(default)]
    pub sim_grid: u32,
}

impl StylizerArgs {
    /// How the SIM sees positions.
    pub fn position(&self) -> StylePositionConfig {
        StylePositionConfig::new()
            .with_position_freqs(self.position_freqs)
            .with_grid_resolution(self.sim_grid)
    }
}

impl Default for StylizerArgs {
    fn default() -> Self {
        crate::config::clap_defaults()
    }
}

/// Implements [`RunConfig`](super::RunConfig) for a scene variant's config made of the shared
/// groups (its paintings in `style`, its seed in `schedule`, its pretrained run in
/// `source.from`), and what every such config has: clap's defaults, `from_file` (a run's
/// `config.json`) and `kind` (`$what` names the pretrained model a stylization needs, "a NeRF").
macro_rules! scene_run_config {
    ($config:ty, $what:literal) => {
        impl Default for $config {
            fn default() -> Self {
                $crate::config::clap_defaults()
            }
        }

        impl $config {
            /// Reads a run's `config.json`.
            pub fn from_file(path: &std::path::Path) -> anyhow::Result<Self> {
                $crate::config::read_json(path)
            }

            /// Which kind of run this is (see `SourceArgs::kind`).
            pub fn kind(&self) -> anyhow::Result<$crate::run::RunKind> {
                self.source.kind(&self.style.styles, $what)
            }
        }

        impl $crate::run::RunConfig for $config {
            fn style(&self) -> &$crate::run::StyleArgs {
                &self.style
            }

            fn seed(&self) -> u64 {
                self.schedule.seed
            }

            fn base_run(&self) -> Option<&std::path::Path> {
                self.source.from.as_deref()
            }
        }
    };
}
pub(crate) use scene_run_config;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_style_loss_left_unset_takes_the_variants_default_and_old_runs_read_as_gram() {
        let mut flags = StyleArgs::default();
        assert_eq!(flags.style_loss, None);
        flags.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(flags.loss(), StyleLoss::Nnfm);
        let mut chosen = StyleArgs {
            style_loss: Some(StyleLoss::MeanStd),
            ..StyleArgs::default()
        };
        chosen.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(chosen.loss(), StyleLoss::MeanStd);
        // NNFM is guided by default, unless a radius is given; the other losses have none.
        assert_eq!(flags.match_radius, Some(DEFAULT_MATCH_RADIUS));
        assert_eq!(
            flags.texture_match_radius,
            Some(DEFAULT_TEXTURE_MATCH_RADIUS)
        );
        assert_eq!(chosen.match_radius, None);
        assert_eq!(chosen.texture_match_radius, None);
        // A radius given alone holds at every layer.
        let mut wide = StyleArgs {
            match_radius: Some(2.0),
            ..StyleArgs::default()
        };
        wide.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(wide.match_radius, Some(2.0));
        assert_eq!(wide.texture_match_radius, None);
        // A texture radius given alone keeps the default palette radius.
        let mut texture = StyleArgs {
            texture_match_radius: Some(1.0),
            ..StyleArgs::default()
        };
        texture.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(texture.match_radius, Some(DEFAULT_MATCH_RADIUS));
        assert_eq!(texture.texture_match_radius, Some(1.0));
        // A run saved with one radius, before the texture radius existed, resumes with one.
        let one: StyleArgs = serde_json::from_str(
            r#"{"styles": ["a.png"], "style_size": 256, "patch": 64, "style_loss": "nnfm", "match_radius": 0.2}"#,
        )
        .expect("a style group from before the texture radius parses");
        let mut resumed = one.clone();
        resumed.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(resumed, one);
        assert_eq!(resumed.texture_match_radius, None);
        // A run folder written before the choice existed has no field: it ran Gram.
        let old: StyleArgs = serde_json::from_str(r#"{"styles": ["a.png"], "style_size": 256}"#)
            .expect("an old style group parses");
        assert_eq!(old.loss(), StyleLoss::Gram);
        // Nor a match radius: its NNFM, if it had one, was unguided.
        assert_eq!(old.match_radius, Some(2.0));
        // Resolving the defaults (as `--resume` does) keeps what the old runs ran, so their
        // configs still compare equal: Gram before the choice, unguided NNFM before the radius.
        let mut resumed = StyleArgs {
            patch: 64,
            ..old.clone()
        };
        let saved = resumed.clone();
        resumed.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(resumed, saved);
        let nnfm: StyleArgs = serde_json::from_str(
            r#"{"styles": ["a.png"], "style_size": 256, "patch": 64, "style_loss": "nnfm"}"#,
        )
        .expect("a style group from before the radius parses");
        let mut resumed = nnfm.clone();
        resumed.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(resumed, nnfm);
        assert_eq!(resumed.match_radius, Some(2.0));
    }

    /// An interrupted stylization written before `style_loss` and `match_radius` existed
    /// resumes from its own config (`--resume --config RUN/config.json`): read back and given
    /// the variant's defaults, it still equals what the run saved.
    #[test]
    fn a_run_saved_before_the_loss_choices_resumes_from_its_own_config() {
        use crate::config::{merge_with_file, write_run_config};
        use crate::nerf::NerfRunConfig;
        use clap::{CommandFactory, FromArgMatches, Parser};
        #[derive(Parser)]
        struct Cmd {
            #[command(flatten)]
            cfg: NerfRunConfig,
        }
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("run");
        let mut cfg = NerfRunConfig::default();
        cfg.style.styles = vec![dir.path().join("starry.jpg")];
        cfg.style.resolve(64, 256, StyleLoss::Nnfm);
        let mut saved = serde_json::to_value(&cfg).unwrap();
        let fields = saved.as_object_mut().unwrap();
        assert!(fields.remove("style_loss").is_some() && fields.remove("match_radius").is_some());
        std::fs::create_dir_all(&run).unwrap();
        let file = run.join("config.json");
        std::fs::write(&file, serde_json::to_string(&saved).unwrap()).unwrap();

        let matches = Cmd::command().get_matches_from(["ins-cli"]);
        let cli = Cmd::from_arg_matches(&matches).unwrap().cfg;
        let mut resumed = merge_with_file(cli, &matches, Some(&file)).unwrap();
        resumed.style.resolve(64, 256, StyleLoss::Nnfm);
        assert_eq!(resumed.style.loss(), StyleLoss::Gram, "it ran Gram");
        write_run_config(&resumed, "nerf", &run, true).expect("the old run resumes");
        // Today's defaults (guided NNFM) are another configuration, and are refused.
        let e = write_run_config(&cfg, "nerf", &run, true).unwrap_err();
        assert!(format!("{e:#}").contains("another configuration"), "{e:#}");
    }

    #[test]
    fn scene_stylizers_get_a_texture_grid_unless_an_old_run_had_none() {
        assert_eq!(StylizerArgs::default().sim_grid, 256);
        let old: StylizerArgs =
            serde_json::from_str(r#"{"sim_width": 64, "position_freqs": 4}"#).expect("parses");
        assert_eq!(old.sim_grid, 0);
    }
}
