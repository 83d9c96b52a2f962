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
use super::lifecycle::Run;

/// How a task starts: from the data (pretraining) or from a pretrained run (stylizing).
pub enum Start<V: Variant> {
    /// Pretraining on freshly loaded data.
    Fresh(V::Data),
    /// Stylizing the pretrained run (its data, model and extra state).
    From(Run<V>),
}

/// One variant of INS (NeRF, IDR, SIREN): the parts of a run that differ between them.
pub trait Variant: Sized + 'static {
    /// Lowercase name, as in `ins-cli train <name>`.
    const NAME: &'static str;
    /// Flags and `config.json` of a run.
    type Config: Clone + PartialEq + Default + Serialize + DeserializeOwned + clap::Args;
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
    type Extra;

    /// Pretraining or stylizing, from the config (an error for contradictory sources).
    fn kind(cfg: &Self::Config) -> Result<RunKind>;
    /// The paintings and patch settings.
    fn style(cfg: &Self::Config) -> &StyleArgs;
    /// The paintings and patch settings, to resolve.
    fn style_mut(cfg: &mut Self::Config) -> &mut StyleArgs;
    /// The pretrained run a stylizing config starts from.
    fn base_run(cfg: &Self::Config) -> Option<&Path>;
    /// The run's seed.
    fn seed(cfg: &Self::Config) -> u64;

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
    /// The number of styles a model renders (0 without a stylizer).
    fn n_styles(model: &Self::Model) -> usize;
    /// The extra state of a run from its checkpoint's task state (`at` names the file).
    fn decode_extra(task_state: Option<&[u8]>, at: &Path) -> Result<Self::Extra>;

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
    /// stylized images), on the plain `device`.
    fn final_report(
        model: &Self::Model,
        task: &Self::Task,
        cfg: &Self::Config,
        folder: &RunFolder,
        device: &Device,
    ) -> Result<()>;
}
