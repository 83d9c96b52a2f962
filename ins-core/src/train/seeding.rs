//! Seeded model construction.
//!
//! Burn's random generator belongs to the device and is shared by every thread, so two models
//! initialised at the same time interleave their draws. Seeding and drawing under one lock
//! makes "same seed, same model" hold even when several runs share a process.
//!
//! Burn draws a parameter's initial values lazily, at its first use, so the lock is held until
//! every parameter of the built model has drawn its values.

use std::sync::Mutex;

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;

static INIT_LOCK: Mutex<()> = Mutex::new(());

/// Seeds `device` with `seed` and builds a model with `build` while no other seeded build
/// runs, its parameters' values drawn before the lock is released.
pub fn seeded<M: Module>(device: &Device, seed: u64, build: impl FnOnce() -> M) -> M {
    let _guard = INIT_LOCK.lock().unwrap_or_else(|p| p.into_inner());
    device.seed(seed);
    let model = build();
    model.visit(&mut DrawNow);
    model
}

/// Makes each float parameter draw its lazily initialised values.
struct DrawNow;

impl ModuleVisitor for DrawNow {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let _ = param.val();
    }
}

#[cfg(test)]
mod tests {
    use burn::nn::LinearConfig;

    use super::*;

    #[test]
    fn a_seeded_model_has_drawn_its_values_when_the_lock_is_released() {
        let d = Device::flex();
        let lazy = LinearConfig::new(4, 3).init(&d);
        assert!(
            !lazy.weight.is_initialized(),
            "Burn no longer draws lazily: this test no longer tests anything"
        );
        let m = seeded(&d, 7, || LinearConfig::new(4, 3).init(&d));
        assert!(m.weight.is_initialized());
        assert!(m.bias.as_ref().unwrap().is_initialized());
    }
}
