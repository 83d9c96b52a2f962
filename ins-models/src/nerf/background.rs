//! The background colour of an object capture in a box, learned while pretraining.
//!
//! Why: a ray that nothing in the field stops shows the background colour. Black (the old
//! default for captures) made a field explain a plain backdrop (a white table, a wall) with
//! haze between the cameras and the object, which every other view then looks through. With
//! the background the colour that best fits what the field lets through, and the field
//! starting nearly transparent (see `run.rs`), a plain backdrop costs nothing and the field
//! holds the object alone (a phone-like capture of lego on white: 24.4 dB held out after 500
//! steps, against 11.8 with haze).
//!
//! Not a model parameter: the best constant has a closed form per batch,
//! `Σ Tᵢ (targetᵢ − fieldᵢ) / Σ Tᵢ²` (`T` the ray's transmittance, `field` its colour without
//! background), kept as running sums so that a resumed run continues exactly.

use ins_scene::data::{Scene, SceneFormat};

/// Whether `scene` learns its background: an object-centred capture (COLMAP, transforms.json)
/// framed in a box, its photos not composited on a known colour. Datasets keep theirs (white
/// for NeRF-synthetic, black for DTU); a contracted capture has all of space to paint its
/// background in; a forward-facing one ends its rays at the far plane.
pub fn learns_background(scene: &Scene) -> bool {
    matches!(scene.format, SceneFormat::Colmap | SceneFormat::Transforms)
        && !scene.forward_facing
        && scene.contraction.is_none()
        && !scene.white_background
}

/// The background a scene has without learning one: white for photos composited on white
/// (NeRF-synthetic), black otherwise; a learned background starts from it.
pub fn fixed_background(scene: &Scene) -> [f32; 3] {
    if scene.white_background {
        [1.0; 3]
    } else {
        [0.0; 3]
    }
}

/// Running sums of the closed-form fit, decayed per step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LearnedBackground {
    /// Decayed `Σ T (target − field)` per channel.
    pub num: [f32; 3],
    /// Decayed `Σ T²`.
    pub den: f32,
}

/// How much of the sums one step keeps: about the last 20 steps count.
const DECAY: f32 = 0.95;

impl LearnedBackground {
    /// The colour, `fallback` before any ray has let light through.
    pub fn colour(&self, fallback: [f32; 3]) -> [f32; 3] {
        if self.den <= 1e-6 {
            return fallback;
        }
        self.num.map(|n| (n / self.den).clamp(0.0, 1.0))
    }

    /// Adds a batch's sums.
    pub fn update(&mut self, num: [f32; 3], den: f32) {
        if !(num.iter().all(|v| v.is_finite()) && den.is_finite()) {
            return;
        }
        for (s, n) in self.num.iter_mut().zip(num) {
            *s = DECAY * *s + n;
        }
        self.den = DECAY * self.den + den;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_to_the_colour_that_fits_the_transmitted_light() {
        // Rays letting through half the light, whose targets are the field's colour plus half
        // of a grey-blue backdrop.
        let backdrop = [0.3, 0.5, 0.9];
        let mut bg = LearnedBackground::default();
        assert_eq!(bg.colour([0.0; 3]), [0.0; 3]);
        for _ in 0..100 {
            let t = [0.5f32; 8];
            let num = backdrop.map(|b| t.iter().map(|t| t * t * b).sum());
            let den = t.iter().map(|t| t * t).sum();
            bg.update(num, den);
        }
        for (got, want) in bg.colour([0.0; 3]).iter().zip(backdrop) {
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
        // A batch that lets nothing through leaves the colour; a NaN batch is ignored.
        let before = bg.colour([0.0; 3]);
        bg.update([f32::NAN; 3], 1.0);
        bg.update([0.0; 3], 0.0);
        let after = bg.colour([0.0; 3]);
        for (a, b) in before.iter().zip(after) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}
