//! Any run folder, whichever variant wrote it. A run records its variant in `config.json`
//! (`"variant": "nerf"`); [`RunVariant::of`] reads it and [`AnyRun::load`] loads the run. This
//! is the one place a new variant registers: the viewer, `export mesh`, `eval consistency` and
//! the report load runs through it.

use std::path::Path;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use ins_core::train::RunFolder;

use super::lifecycle::Run;
use super::scene_render::SceneRender;
use super::variant::Variant;
use crate::config::{VARIANT_FIELD, read_json};
use crate::idr::{Idr, IdrRun};
use crate::nerf::{Nerf, NerfRun};
use crate::siren::{Siren, SirenRun};

/// The variants a run folder can hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunVariant {
    /// An image (SIREN + INS).
    Siren,
    /// A radiance field (NeRF + INS).
    Nerf,
    /// A surface (IDR + INS).
    Idr,
}

impl RunVariant {
    /// Every variant, in the order a run folder written before the name was recorded is tried.
    pub const ALL: [Self; 3] = [Self::Siren, Self::Nerf, Self::Idr];

    /// The name `config.json` records and commands take (`ins-cli train <key>`).
    pub fn key(self) -> &'static str {
        match self {
            Self::Siren => Siren::KEY,
            Self::Nerf => Nerf::KEY,
            Self::Idr => Idr::KEY,
        }
    }

    /// The name people read (SIREN, NeRF, IDR).
    pub fn name(self) -> &'static str {
        match self {
            Self::Siren => Siren::NAME,
            Self::Nerf => Nerf::NAME,
            Self::Idr => Idr::NAME,
        }
    }

    /// The variant of the run folder `dir`, from its `config.json`. A folder written before
    /// runs recorded their variant is told by the config that parses as one variant's.
    pub fn of(dir: &Path) -> Result<Self> {
        let path = RunFolder::new(dir).config();
        if !path.is_file() {
            bail!("{} is not a run folder (no config.json)", dir.display());
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let value: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{}: malformed config", path.display()))?;
        match value.get(VARIANT_FIELD) {
            Some(serde_json::Value::String(key)) => Self::ALL
                .into_iter()
                .find(|v| v.key() == key)
                .with_context(|| {
                    format!(
                        "{}: a run of variant `{key}`, which this build does not know ({})",
                        path.display(),
                        Self::keys()
                    )
                }),
            Some(other) => bail!(
                "{}: malformed config: `{VARIANT_FIELD}` is {other}, not a name ({})",
                path.display(),
                Self::keys()
            ),
            None => Self::ALL
                .into_iter()
                .find(|v| v.parses(&path))
                .with_context(|| {
                    format!(
                        "{}: not the config of a {} run",
                        path.display(),
                        Self::ALL.map(Self::name).join(", ")
                    )
                }),
        }
    }

    /// Whether the config file at `path` parses as this variant's.
    fn parses(self, path: &Path) -> bool {
        match self {
            Self::Siren => read_json::<<Siren as Variant>::Config>(path).is_ok(),
            Self::Nerf => read_json::<<Nerf as Variant>::Config>(path).is_ok(),
            Self::Idr => read_json::<<Idr as Variant>::Config>(path).is_ok(),
        }
    }

    fn keys() -> String {
        Self::ALL.map(Self::key).join(", ")
    }
}

/// A run folder of any variant, loaded back. (One per command: the variants' sizes may differ.)
#[allow(clippy::large_enum_variant)]
pub enum AnyRun {
    /// An image.
    Siren(SirenRun),
    /// A radiance field.
    Nerf(NerfRun),
    /// A surface.
    Idr(IdrRun),
}

impl AnyRun {
    /// Loads the run folder `dir` on `device`, whichever variant wrote it.
    pub fn load(dir: &Path, device: &Device) -> Result<Self> {
        Ok(match RunVariant::of(dir)? {
            RunVariant::Siren => Self::Siren(Run::load(dir, device)?),
            RunVariant::Nerf => Self::Nerf(Run::load(dir, device)?),
            RunVariant::Idr => Self::Idr(Run::load(dir, device)?),
        })
    }

    /// Which variant the run is.
    pub fn variant(&self) -> RunVariant {
        match self {
            Self::Siren(_) => RunVariant::Siren,
            Self::Nerf(_) => RunVariant::Nerf,
            Self::Idr(_) => RunVariant::Idr,
        }
    }

    /// The run as a 3D scene (NeRF, IDR); a SIREN run is an image, and `what` (what the caller
    /// makes, e.g. "a mesh") says why it does not fit.
    pub fn into_scene(self, what: &str) -> Result<Box<dyn SceneRender>> {
        match self {
            Self::Nerf(run) => Ok(Box::new(run)),
            Self::Idr(run) => Ok(Box::new(run)),
            Self::Siren(run) => bail!(
                "{} is a SIREN run (an image): {what} needs a NeRF or IDR run",
                run.dir.display()
            ),
        }
    }
}

/// Loads the NeRF or IDR run folder `dir` as a 3D scene; `what` says what the caller does with
/// it, for the error a SIREN run gets.
pub fn load_scene_run(dir: &Path, device: &Device, what: &str) -> Result<Box<dyn SceneRender>> {
    AnyRun::load(dir, device)?.into_scene(what)
}
