//! What a variant brings to the shared run lifecycle ([`super::lifecycle`]): its configuration,
//! data, model, task and phases. Everything else about a run (the folder, its lock and config,
//! seeding, the perceptual loss, pretraining, stylizing a base run, loading a run back) is
//! written once, for every variant.

use std::path::Path;

use anyhow::Result;
use burn::prelude::*;
use ins_core::loss::{LossWeights, PerceptualLoss};
use ins_core::train::{Objective, Optimizable, Phase, RunFolder, Task};
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::args::{RunKind, StyleArgs};

/// Scores of a finished run's final renders by name (see [`Variant::final_report`]).
pub type FinalScores = std::collections::BTreeMap<String, f64>;
use super::lifecycle::Run;

/// What the run lifecycle reads of any variant's configuration: its paintings, its seed and,
/// for a stylizing run, the pretrained run it starts from. Scene variants whose configs are made
/// of the shared argument groups get it from the `scene_run_config!` macro of [`super::args`].
pub trait RunConfig:
    Clone + PartialEq + Default + Serialize + DeserializeOwned + clap::Args
{
    /// The paintings and the perceptual loss's settings.
    fn style(&self) -> &StyleArgs;
    /// The run's seed.
    fn seed(&self) -> u64;
    /// The pretrained run a stylizing config starts from (none for a variant that fits and
    /// stylizes in one run).
    fn base_run(&self) -> Option<&Path> {
        None
    }
}

/// What a run keeps beside its model in a checkpoint (the task's state, e.g. NeRF's occupancy
/// grid), decoded when the run is loaded back; nothing for most variants.
pub trait RunState: Sized {
    /// The state from a checkpoint's task bytes (`at` names the file for errors).
    fn decode(task_state: Option<&[u8]>, at: &Path) -> Result<Self>;
}

impl RunState for () {
    fn decode(_task_state: Option<&[u8]>, _at: &Path) -> Result<()> {
        Ok(())
    }
}

/// How a task starts: from the data (pretraining) or from a pretrained run (stylizing).
pub enum Start<V: Variant> {
    /// Pretraining on freshly loaded data.
    Fresh(V::Data),
    /// Stylizing the pretrained run (its data, model and extra state).
    From(Run<V>),
}

/// One variant of INS (NeRF, IDR, SIREN): the parts of a run that differ between them.
pub trait Variant: Sized + 'static {
    /// The name people read (NeRF, IDR, SIREN).
    const NAME: &'static str;
    /// The name a run folder records in its `config.json` and commands take
    /// (`ins-cli train <key>`): lowercase.
    const KEY: &'static str;
    /// Flags and `config.json` of a run.
    type Config: RunConfig;
    /// What a run learns from: a scene, or an image.
    type Data;
    /// The trained model.
    type Model: Optimizable;
    /// What a phase computes.
    type Objective: Objective;
    /// The training task.
    type Task: Task<Model = Self::Model, Objective = Self::Objective>;
    /// What a run folder keeps beside the model (the task's state in a checkpoint, e.g. NeRF's
    /// occupancy grid), decoded when a run is loaded.
    type Extra: RunState;

    /// Pretraining or stylizing, from the config (an error for contradictory sources).
    fn kind(cfg: &Self::Config) -> Result<RunKind>;

    /// Loads the data the config names (for a stylized run's config, its base's), writing back
    /// settings chosen from the data (an automatic downscale).
    fn load_data(cfg: &mut Self::Config) -> Result<Self::Data>;
    /// Checks that data re-read for a run is framed as it was when the run's field was trained
    /// (`field_run` is the folder of the run that trained it); by default nothing to check.
    fn check_data(_data: &Self::Data, _field_run: &RunFolder) -> Result<()> {
        Ok(())
    }
    /// About `max` colours of the data's training photos, on the object where it has masks
    /// (what colour transfer maps to the painting's palette).
    fn palette(data: &Self::Data, max: usize) -> Vec<[f32; 3]>;
    /// Fills the config's defaults that depend on the kind of run and the data (steps,
    /// learning rate, patch), so `config.json` holds the values that ran.
    fn resolve(cfg: &mut Self::Config, kind: RunKind, data: &Self::Data);
    /// Stylizing `base` (the config of the run at `from`): refuses a base of another
    /// architecture and takes over its scene settings.
    fn inherit(cfg: &mut Self::Config, base: &Self::Config, from: &Path) -> Result<()>;

    /// A fresh model (weights drawn from the device's seed).
    fn new_model(cfg: &Self::Config, data: &Self::Data, device: &Device) -> Self::Model;
    /// The model with a fresh SIM and AM for `n_styles` styles (the AM starting as the
    /// identity), or unchanged where the model always has them (SIREN).
    fn add_stylizer(
        model: Self::Model,
        cfg: &Self::Config,
        n_styles: usize,
        device: &Device,
    ) -> Self::Model;

    /// The task of a run, on the autodiff `device`, with the paintings' loss where the run
    /// stylizes.
    fn task(
        cfg: &Self::Config,
        start: Start<Self>,
        style: Option<PerceptualLoss>,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<Self::Task>;
    /// The phases of a run of `kind` (config resolved), the perceptual terms weighed by
    /// `weights`.
    fn phases(
        cfg: &Self::Config,
        kind: RunKind,
        weights: LossWeights,
    ) -> Vec<Phase<Self::Objective>>;
    /// What a finished run writes besides its checkpoint (pictures of held-out views, the
    /// stylized images), on the plain `device`, and the scores of those views (means over
    /// them, with their count as `views`; empty where nothing is held out).
    fn final_report(
        model: &Self::Model,
        task: &Self::Task,
        cfg: &Self::Config,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<FinalScores>;
}
