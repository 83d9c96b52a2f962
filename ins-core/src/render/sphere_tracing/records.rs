//! The tracer's records of each ray: the stretches it samples, the sign changes it brackets,
//! its closest sample and its march's smallest one with their neighbours.

/// A sign change along ray `ray`: `f(t0) ≥ 0 > f(t1)`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Bracket {
    pub(super) ray: usize,
    pub(super) t0: f32,
    pub(super) f0: f32,
    pub(super) t1: f32,
    pub(super) f1: f32,
}

impl Bracket {
    /// The secant estimate of the crossing, inside the bracket.
    pub(super) fn secant(&self) -> f32 {
        let d = self.f1 - self.f0;
        if d.abs() > 1e-12 {
            // max/min, not clamp: bounds read from a diverged field (NaN) must not panic.
            (self.t0 - self.f0 * (self.t1 - self.t0) / d)
                .max(self.t0)
                .min(self.t1)
        } else {
            0.5 * (self.t0 + self.t1)
        }
    }
}

/// A stretch of a ray to sample: `count` evenly spaced samples from `t0` to `t1`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Stretch {
    pub(super) ray: usize,
    pub(super) t0: f32,
    pub(super) t1: f32,
    pub(super) count: usize,
}

impl Stretch {
    pub(super) fn at(&self, j: usize) -> f32 {
        self.t0 + (self.t1 - self.t0) * j as f32 / (self.count - 1).max(1) as f32
    }
}

/// The closest sample of each ray so far.
pub(super) struct Closest {
    pub(super) t: Vec<f32>,
    pub(super) f: Vec<f32>,
}

/// The march sample of a ray with the smallest value, with the samples before and after it.
#[derive(Clone, Copy)]
pub(super) struct MarchMinimum {
    pub(super) before: (f32, f32),
    pub(super) at: (f32, f32),
    pub(super) after: (f32, f32),
}

impl MarchMinimum {
    pub(super) const NONE: (f32, f32) = (f32::NAN, f32::NAN);
    /// Before the first sample.
    pub(super) const EMPTY: Self = Self {
        before: Self::NONE,
        at: Self::NONE,
        after: Self::NONE,
    };

    /// Takes the next march sample `(t, f)`, `previous` being the one before it. Written as
    /// "not ≥" so that the first sample replaces the NaN of [`Self::EMPTY`].
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    pub(super) fn offer(&mut self, previous: (f32, f32), sample: (f32, f32)) {
        if !(sample.1 >= self.at.1) {
            *self = Self {
                before: previous,
                at: sample,
                after: Self::NONE,
            };
        } else if self.after.1.is_nan() {
            self.after = sample;
        }
    }

    /// The vertex of the parabola through the three samples (the smallest sample alone when
    /// it has no neighbour on either side, or the three do not open upwards).
    pub(super) fn vertex(&self) -> f32 {
        let ((t0, f0), (t1, f1), (t2, f2)) = (self.before, self.at, self.after);
        if !(f0.is_finite() && f2.is_finite()) {
            return t1;
        }
        let (a, b) = ((t1 - t0) * (f1 - f2), (t1 - t2) * (f1 - f0));
        let den = a - b;
        if den.abs() < 1e-12 {
            return t1;
        }
        let v = t1 - 0.5 * ((t1 - t0) * a - (t1 - t2) * b) / den;
        if v.is_finite() { v.max(t0).min(t2) } else { t1 }
    }
}

impl Closest {
    pub(super) fn offer(&mut self, ray: usize, t: f32, f: f32) {
        if f.is_finite() && f < self.f[ray] {
            self.f[ray] = f;
            self.t[ray] = t;
        }
    }
}
