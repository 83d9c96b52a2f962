//! Optimizer groups: one Adam per named part of a model, each with its own learning-rate
//! multiplier and an on/off switch (freezing).
//!
//! Burn's `ModuleOptimizer` takes one learning rate per step; a group per sub-module gives
//! per-module rates without touching Burn, and a frozen group is simply not stepped.

use std::collections::BTreeMap;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::Gradients;
use serde::{Deserialize, Serialize};

/// A model whose parameters are split into named groups.
pub trait Optimizable: Module + Sized {
    /// The names of the groups, in a fixed order.
    fn group_names() -> &'static [&'static str];
    /// Applies one optimizer step, group by group (`groups.step(name, sub_module, ...)`).
    fn optimize(self, grads: &mut Gradients, lr: f64, groups: &mut OptimGroups) -> Self;
}

/// Learning-rate multiplier and freezing of one group, as configured per phase.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct GroupSetting {
    /// Multiplies the scheduled learning rate.
    pub lr_mult: f64,
    /// A frozen group keeps its parameters.
    pub frozen: bool,
}

impl Default for GroupSetting {
    fn default() -> Self {
        Self {
            lr_mult: 1.0,
            frozen: false,
        }
    }
}

/// One Adam state per group.
pub struct OptimGroups {
    optimizers: BTreeMap<String, ModuleOptimizer>,
    settings: BTreeMap<String, GroupSetting>,
}

impl OptimGroups {
    /// Fresh Adam states for `names`.
    pub fn new(names: &[&str]) -> Self {
        let optimizers = names
            .iter()
            .map(|n| (n.to_string(), AdamConfig::new().with_epsilon(1e-8).init()))
            .collect();
        let settings = names
            .iter()
            .map(|n| (n.to_string(), GroupSetting::default()))
            .collect();
        Self {
            optimizers,
            settings,
        }
    }

    /// Sets the multiplier and freezing of each group named in `settings` (others: default).
    pub fn configure(&mut self, settings: &BTreeMap<String, GroupSetting>) {
        for (name, s) in self.settings.iter_mut() {
            *s = settings.get(name).copied().unwrap_or_default();
        }
    }

    /// Whether the group is frozen now.
    pub fn is_frozen(&self, name: &str) -> bool {
        self.settings.get(name).map(|s| s.frozen).unwrap_or(false)
    }

    /// Steps `module` with the gradients it has in `grads`, unless its group is frozen.
    pub fn step<M: Module>(&mut self, name: &str, module: M, grads: &mut Gradients, lr: f64) -> M {
        let setting = self.settings.get(name).copied().unwrap_or_default();
        if setting.frozen {
            return module;
        }
        let params = GradientsParams::from_module(grads, &module);
        if params.is_empty() {
            return module;
        }
        match self.optimizers.get_mut(name) {
            Some(optim) => optim.step(lr * setting.lr_mult, module, params),
            None => module,
        }
    }

    /// Serialized optimizer states, one blob per group.
    pub fn to_bytes(&self) -> anyhow::Result<BTreeMap<String, Vec<u8>>> {
        let mut out = BTreeMap::new();
        for (name, optim) in &self.optimizers {
            let bytes = optim
                .into_bytes()
                .map_err(|e| anyhow::anyhow!("serializing optimizer group {name}: {e}"))?;
            out.insert(name.clone(), bytes.to_vec());
        }
        Ok(out)
    }

    /// Restores the states written by [`OptimGroups::to_bytes`].
    pub fn load_bytes(&mut self, blobs: BTreeMap<String, Vec<u8>>) -> anyhow::Result<()> {
        for (name, bytes) in blobs {
            let Some(optim) = self.optimizers.remove(&name) else {
                anyhow::bail!("checkpoint has optimizer group {name:?} the model does not");
            };
            let optim = optim
                .from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes))
                .map_err(|e| anyhow::anyhow!("optimizer group {name}: {e}"))?;
            self.optimizers.insert(name, optim);
        }
        Ok(())
    }
}
