//! Seeded model construction.
//!
//! Burn's random generator belongs to the device and is shared by every thread, so two models
//! initialised at the same time interleave their draws. Seeding and drawing under one lock
//! makes "same seed, same model" hold even when several runs share a process.

use std::sync::Mutex;

use burn::prelude::*;

static INIT_LOCK: Mutex<()> = Mutex::new(());

/// Seeds `device` with `seed` and runs `build` while no other seeded build runs.
pub fn seeded<T>(device: &Device, seed: u64, build: impl FnOnce() -> T) -> T {
    let _guard = INIT_LOCK.lock().unwrap_or_else(|p| p.into_inner());
    device.seed(seed);
    build()
}
