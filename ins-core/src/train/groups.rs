//! Optimizer groups: named sets of a model's parameters, each with its own learning-rate
//! multiplier and freezing per phase.
//!
//! A model names its groups by module path ([`GroupSpec`]); [`ParamGroups::resolve`] walks the
//! model once and checks that every trainable parameter falls in exactly one group, so a
//! forgotten sub-module or a misspelt path stops the run before it starts instead of silently
//! never being trained. Freezing switches the parameters' `require_grad` off, so backward does
//! not compute their gradients at all; learning rates go to Burn's optimizer as a
//! [`ModuleLearningRate`] built from the same groups.

use std::collections::BTreeMap;

use burn::module::{Module, ModuleVisitor, Param, ParamGroup, ParamId};
use burn::optim::lr_scheduler::module_lr_scheduler::{ModuleLearningRate, ModuleLrScheduler};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use super::error::TrainError;

/// One optimizer group of a model: a name and the module paths it covers (`"am"` covers every
/// parameter under the field `am`; `"sim.layers.0"` only that layer's).
#[derive(Debug, Clone, Copy)]
pub struct GroupSpec {
    /// Name used by phases (`Phase::freeze("cim")`).
    pub name: &'static str,
    /// Module path prefixes.
    pub modules: &'static [&'static str],
}

impl GroupSpec {
    /// A group covering the listed module paths.
    pub const fn new(name: &'static str, modules: &'static [&'static str]) -> Self {
        Self { name, modules }
    }

    fn covers(&self, path: &str) -> bool {
        self.modules.iter().any(|m| {
            path == *m
                || (path.len() > m.len() && path.starts_with(m) && path.as_bytes()[m.len()] == b'.')
        })
    }
}

/// A model whose parameters are split into named optimizer groups.
pub trait Optimizable: Module + Sized {
    /// The groups, in a fixed order. Every trainable parameter must be in exactly one. A model
    /// whose parts are optional lists only the parts it has.
    fn groups(&self) -> Vec<GroupSpec>;
}

/// Learning-rate multiplier and freezing of one group, as configured per phase.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct GroupSetting {
    /// Multiplies the scheduled learning rate.
    pub lr_mult: f64,
    /// A frozen group keeps its parameters and gets no gradients.
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

/// Every float parameter of a module with its path and whether it is trainable.
pub fn parameter_paths<M: Module>(model: &M) -> Vec<(String, ParamId, bool)> {
    struct Paths {
        stack: Vec<String>,
        out: Vec<(String, ParamId, bool)>,
    }
    impl ModuleVisitor for Paths {
        fn enter_module(&mut self, name: &str, _container: &str) {
            self.stack.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container: &str) {
            self.stack.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.out.push((
                self.stack.join("."),
                param.id,
                param.val().is_require_grad(),
            ));
        }
    }
    let mut v = Paths {
        stack: Vec::new(),
        out: Vec::new(),
    };
    model.visit(&mut v);
    v.out
}

/// The resolved groups of one model: for each group, the paths of its trainable parameters.
#[derive(Debug, Clone)]
pub struct ParamGroups {
    groups: Vec<(String, Vec<String>)>,
}

impl ParamGroups {
    /// Assigns every trainable parameter of `model` to its group, or says which parameter has
    /// no group (or two), and which group covers nothing.
    pub fn resolve<M: Optimizable>(model: &M) -> Result<Self, TrainError> {
        let specs = model.groups();
        let known = specs.iter().map(|g| g.name).collect::<Vec<_>>().join(", ");
        let mut groups: Vec<(String, Vec<String>)> = specs
            .iter()
            .map(|g| (g.name.to_string(), Vec::new()))
            .collect();
        let mut covered = vec![false; specs.len()];
        for (path, _, trainable) in parameter_paths(model) {
            let mut owner: Option<usize> = None;
            for (i, g) in specs.iter().enumerate() {
                if g.covers(&path) {
                    covered[i] = true;
                    if let Some(first) = owner {
                        return Err(TrainError::AmbiguousParameter {
                            path,
                            first: specs[first].name.to_string(),
                            second: g.name.to_string(),
                        });
                    }
                    owner = Some(i);
                }
            }
            match owner {
                Some(i) if trainable => groups[i].1.push(path),
                Some(_) => {}
                None if trainable => {
                    return Err(TrainError::UngroupedParameter {
                        path,
                        known: known.clone(),
                    });
                }
                None => {}
            }
        }
        if let Some(i) = covered.iter().position(|c| !c) {
            return Err(TrainError::EmptyGroup {
                group: specs[i].name.to_string(),
                paths: specs[i].modules.iter().map(|s| s.to_string()).collect(),
            });
        }
        Ok(Self { groups })
    }

    /// Group names, in the model's order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.groups.iter().map(|(n, _)| n.as_str())
    }

    /// Whether the model has a group of this name.
    pub fn contains(&self, name: &str) -> bool {
        self.groups.iter().any(|(n, _)| n == name)
    }

    /// Names joined for messages.
    pub fn known(&self) -> String {
        self.names().collect::<Vec<_>>().join(", ")
    }

    /// Paths of the trainable parameters of a group.
    pub fn paths(&self, name: &str) -> &[String] {
        self.groups
            .iter()
            .find(|(n, _)| n == name)
            .map_or(&[], |(_, p)| p.as_slice())
    }

    fn param_group(paths: &[String]) -> ParamGroup {
        ParamGroup::from_paths(paths.to_vec())
    }

    /// Switches gradients on for the trainable parameters of unfrozen groups and off for those
    /// of frozen ones (groups missing from `settings` are trained).
    pub fn apply_freezing<M: Module>(
        &self,
        mut model: M,
        settings: &BTreeMap<String, GroupSetting>,
    ) -> M {
        for (name, paths) in &self.groups {
            if paths.is_empty() {
                continue;
            }
            let frozen = settings.get(name).is_some_and(|s| s.frozen);
            model = model.set_require_grad_group(Self::param_group(paths), !frozen);
        }
        model
    }

    /// Per-parameter learning rates for one step: `base · lr_mult` of each parameter's group
    /// (0 for frozen groups and for parameters outside every group).
    pub fn learning_rates(
        &self,
        base: f64,
        settings: &BTreeMap<String, GroupSetting>,
    ) -> ModuleLearningRate {
        let mut policy = ModuleLrScheduler::new(0.0f64);
        for (name, paths) in &self.groups {
            if paths.is_empty() {
                continue;
            }
            let s = settings.get(name).copied().unwrap_or_default();
            let lr = if s.frozen { 0.0 } else { base * s.lr_mult };
            policy = policy.with_group(Self::param_group(paths), lr);
        }
        policy.step()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    #[derive(Module, Debug)]
    struct Two {
        a: Linear,
        b: Linear,
    }

    fn two() -> Two {
        let d = Device::flex().autodiff();
        Two {
            a: LinearConfig::new(2, 2).init(&d),
            b: LinearConfig::new(2, 1).init(&d),
        }
    }

    macro_rules! model_with_groups {
        ($name:ident, $groups:expr) => {
            #[derive(Module, Debug)]
            struct $name {
                inner: Two,
            }
            impl Optimizable for $name {
                fn groups(&self) -> Vec<GroupSpec> {
                    $groups.to_vec()
                }
            }
        };
    }

    model_with_groups!(
        Complete,
        &[
            GroupSpec::new("a", &["inner.a"]),
            GroupSpec::new("b", &["inner.b"])
        ]
    );
    model_with_groups!(Forgetful, &[GroupSpec::new("a", &["inner.a"])]);
    model_with_groups!(
        Overlapping,
        &[
            GroupSpec::new("all", &["inner"]),
            GroupSpec::new("b", &["inner.b"])
        ]
    );
    model_with_groups!(
        Misspelt,
        &[
            GroupSpec::new("a", &["inner.a"]),
            GroupSpec::new("b", &["inner.b"]),
            GroupSpec::new("c", &["inner.c"])
        ]
    );

    #[test]
    fn every_trainable_parameter_is_in_exactly_one_group() {
        let g = ParamGroups::resolve(&Complete { inner: two() }).unwrap();
        assert_eq!(g.paths("a"), ["inner.a.weight", "inner.a.bias"]);
        assert_eq!(g.paths("b"), ["inner.b.weight", "inner.b.bias"]);

        let e = ParamGroups::resolve(&Forgetful { inner: two() }).unwrap_err();
        assert!(
            matches!(&e, TrainError::UngroupedParameter { path, .. } if path == "inner.b.weight"),
            "{e}"
        );
        let e = ParamGroups::resolve(&Overlapping { inner: two() }).unwrap_err();
        assert!(matches!(&e, TrainError::AmbiguousParameter { .. }), "{e}");
        let e = ParamGroups::resolve(&Misspelt { inner: two() }).unwrap_err();
        assert!(
            matches!(&e, TrainError::EmptyGroup { group, .. } if group == "c"),
            "{e}"
        );
    }

    #[test]
    fn constants_need_no_group_and_stay_constant() {
        let mut m = Forgetful { inner: two() };
        m.inner.b = m.inner.b.no_grad();
        let g = ParamGroups::resolve(&m).unwrap();
        let mut s = BTreeMap::new();
        s.insert("a".to_string(), GroupSetting::default());
        let m = g.apply_freezing(m, &s);
        assert!(!m.inner.b.weight.val().is_require_grad());
        assert!(m.inner.a.weight.val().is_require_grad());
    }

    #[test]
    fn frozen_groups_get_no_gradient() {
        let m = Complete { inner: two() };
        let g = ParamGroups::resolve(&m).unwrap();
        let mut s = BTreeMap::new();
        s.insert(
            "a".to_string(),
            GroupSetting {
                lr_mult: 1.0,
                frozen: true,
            },
        );
        let m = g.apply_freezing(m, &s);
        let d = m.inner.a.weight.val().device();
        let x = Tensor::<2>::ones([3, 2], &d);
        let grads = m.inner.b.forward(m.inner.a.forward(x)).sum().backward();
        assert!(
            m.inner.a.weight.val().grad(&grads).is_none(),
            "frozen weight got a gradient"
        );
        assert!(m.inner.b.weight.val().grad(&grads).is_some());
        // Unfreezing restores gradients.
        let m = g.apply_freezing(m, &BTreeMap::new());
        let x = Tensor::<2>::ones([3, 2], &d);
        let grads = m.inner.b.forward(m.inner.a.forward(x)).sum().backward();
        assert!(m.inner.a.weight.val().grad(&grads).is_some());
    }

    #[test]
    fn learning_rates_follow_groups() {
        let m = Complete { inner: two() };
        let g = ParamGroups::resolve(&m).unwrap();
        let mut s = BTreeMap::new();
        s.insert(
            "b".to_string(),
            GroupSetting {
                lr_mult: 0.1,
                frozen: false,
            },
        );
        let lr = g.learning_rates(2.0, &s);
        assert_eq!(
            lr.lr_from_param(m.inner.a.weight.id, Some("inner.a.weight")),
            2.0
        );
        let b = lr.lr_from_param(m.inner.b.bias.as_ref().unwrap().id, Some("inner.b.bias"));
        assert!((b - 0.2).abs() < 1e-12, "{b}");
    }
}
