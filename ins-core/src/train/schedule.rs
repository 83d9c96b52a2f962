//! Learning-rate schedule: `lr · decay^(step / decay_steps)` (NeRF's exponential decay).

use serde::{Deserialize, Serialize};

/// Exponential decay.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct LrSchedule {
    /// Learning rate at step 0.
    pub base: f64,
    /// Factor reached after `decay_steps` steps (NeRF: 0.1).
    pub decay: f64,
    /// Steps over which the rate is multiplied by `decay`.
    pub decay_steps: f64,
}

impl LrSchedule {
    /// A constant rate.
    pub fn constant(base: f64) -> Self {
        Self {
            base,
            decay: 1.0,
            decay_steps: 1.0,
        }
    }

    /// The rate at `step` (counted from the start of the phase).
    pub fn at(&self, step: usize) -> f64 {
        self.base * self.decay.powf(step as f64 / self.decay_steps.max(1.0))
    }
}
