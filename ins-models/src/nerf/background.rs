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
//! background), kept as running sums so that a resumed run continues exactly. While training
//! the sums stay on the device ([`BackgroundFit`]): reading four numbers back every step made
//! a GPU wait for the host at every step; they are read only for a picture or a checkpoint.

use burn::prelude::*;
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

/// [`LearnedBackground`]'s sums and colour kept on the device while pretraining: the same
/// arithmetic in the same order, without a read-back per step.
#[derive(Debug, Clone)]
pub struct BackgroundFit {
    /// Decayed `Σ T (target − field)`, `[3]`.
    num: Tensor<1>,
    /// Decayed `Σ T²`, `[1]`.
    den: Tensor<1>,
    /// The colour the sums give, the previous one while they are empty, `[3]`.
    colour: Tensor<1>,
}

impl BackgroundFit {
    /// Continues from `sums`, showing `fallback` until they give a colour.
    pub fn new(sums: LearnedBackground, fallback: [f32; 3], device: &Device) -> Self {
        Self {
            num: Tensor::from_floats(sums.num, device),
            den: Tensor::from_floats([sums.den], device),
            colour: Tensor::from_floats(sums.colour(fallback), device),
        }
    }

    /// Composites `field` `[R, 3]` (rendered over black, the rays letting `1 − opacity`
    /// through, `opacity` `[R]`) over the current colour, then adds the batch's sums against
    /// `target` `[R, 3]`. The gradient reaches the field and its opacity; the colour is a
    /// constant of the step. A batch whose sums are not finite leaves the fit as it was.
    pub fn composite_and_fit(
        &mut self,
        field: Tensor<2>,
        opacity: Tensor<1>,
        target: Tensor<2>,
    ) -> Tensor<2> {
        let [r, _] = field.dims();
        let rest = opacity.neg().add_scalar(1.0).reshape([r, 1]);
        let pred = field.clone() + rest.clone() * self.colour.clone().reshape([1, 3]);
        let through = rest.detach();
        let residual = target - field.detach();
        let num = (through.clone() * residual).sum_dim(0).reshape([3]);
        let den = (through.clone() * through).sum().reshape([1]);
        let total = num.clone().sum() + den.clone();
        let finite = total
            .clone()
            .is_nan()
            .bool_not()
            .bool_and(total.is_inf().bool_not());
        let decayed = |old: Tensor<1>, add: Tensor<1>| {
            let n = old.dims()[0];
            let keep = finite.clone().expand([n]);
            old.clone().mask_where(keep, old.mul_scalar(DECAY) + add)
        };
        self.num = decayed(self.num.clone(), num);
        self.den = decayed(self.den.clone(), den);
        let has_light = self.den.clone().greater_elem(1e-6).expand([3]);
        let fitted = (self.num.clone() / self.den.clone().expand([3])).clamp(0.0, 1.0);
        self.colour = self.colour.clone().mask_where(has_light, fitted);
        pred
    }

    /// The sums and colour, read back (one transfer).
    pub fn read(&self) -> (LearnedBackground, [f32; 3]) {
        let v = Tensor::cat(
            vec![self.num.clone(), self.den.clone(), self.colour.clone()],
            0,
        )
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap_or_else(|_| vec![0.0; 7]);
        let sums = LearnedBackground {
            num: [v[0], v[1], v[2]],
            den: v[3],
        };
        (sums, [v[4], v[5], v[6]])
    }
}

/// A NeRF task's background: the scene's colour, or for a capture that learns one, its fit on
/// the device with the colour last read from it (a pretraining step reads nothing).
#[derive(Debug, Clone)]
pub struct SceneBackground {
    colour: [f32; 3],
    fit: Option<BackgroundFit>,
    /// Whether the fit moved since `colour` was read from it.
    unread: bool,
}

impl SceneBackground {
    /// `scene`'s fixed colour, learned from there where the scene learns one.
    pub fn for_scene(scene: &Scene, device: &Device) -> Self {
        let colour = fixed_background(scene);
        let fit = learns_background(scene)
            .then(|| BackgroundFit::new(LearnedBackground::default(), colour, device));
        Self {
            colour,
            fit,
            unread: false,
        }
    }

    /// Continues from a pretrained run's sums (and the colour they give).
    pub fn adopt(&mut self, sums: LearnedBackground, device: &Device) {
        self.colour = sums.colour(self.colour);
        self.fit = Some(BackgroundFit::new(sums, self.colour, device));
        self.unread = false;
    }

    /// The colour now, read from the device if the fit moved since the last read.
    pub fn now(&self) -> [f32; 3] {
        match &self.fit {
            Some(fit) if self.unread => fit.read().1,
            _ => self.colour,
        }
    }

    /// [`now`](Self::now), remembered until the fit moves again.
    pub fn read(&mut self) -> [f32; 3] {
        self.colour = self.now();
        self.unread = false;
        self.colour
    }

    /// The colour a pretraining step renders over: black where the fit composites its own.
    pub fn rendered_over(&self) -> [f32; 3] {
        if self.fit.is_some() {
            [0.0; 3]
        } else {
            self.colour
        }
    }

    /// A pretraining step's colour `[R, 3]` from the render over
    /// [`rendered_over`](Self::rendered_over) (see [`BackgroundFit::composite_and_fit`]).
    pub fn composite_and_fit(
        &mut self,
        rendered: Tensor<2>,
        opacity: Tensor<1>,
        target: Tensor<2>,
    ) -> Tensor<2> {
        match self.fit.as_mut() {
            Some(fit) => {
                self.unread = true;
                fit.composite_and_fit(rendered, opacity, target)
            }
            None => rendered,
        }
    }

    /// The learned sums, read (for a checkpoint).
    pub fn sums(&self) -> Option<LearnedBackground> {
        self.fit.as_ref().map(|fit| fit.read().0)
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

    /// The device fit gives the host's sums and colours step by step, ignores a NaN batch,
    /// and composites with the colour of the steps before.
    #[test]
    fn the_device_fit_follows_the_host_sums() {
        let device = Device::flex();
        let mut host = LearnedBackground::default();
        let mut fit = BackgroundFit::new(host, [0.0; 3], &device);
        let rgb = |v: &[f32]| Tensor::<1>::from_floats(v, &device).reshape([v.len() / 3, 3]);
        let mut colour = [0.0f32; 3];
        for step in 0..6 {
            let s = step as f32;
            let field = [0.1, 0.2, 0.3, 0.05 * s, 0.0, 0.4];
            let opacity = [0.5, 0.25 + 0.1 * s];
            let target = [0.4, 0.5, 0.9, 0.7, 0.1 * s, 0.6];
            let target = if step == 3 { [f32::NAN; 6] } else { target };
            let pred = fit.composite_and_fit(
                rgb(&field),
                Tensor::from_floats(opacity, &device),
                rgb(&target),
            );
            let pred = pred.into_data().try_to_vec::<f32>().unwrap();
            let mut num = [0.0f32; 3];
            let mut den = 0.0f32;
            for ray in 0..2 {
                let t = 1.0 - opacity[ray];
                for c in 0..3 {
                    let want = field[3 * ray + c] + t * colour[c];
                    assert!((pred[3 * ray + c] - want).abs() < 1e-6, "step {step}");
                    num[c] += t * (target[3 * ray + c] - field[3 * ray + c]);
                }
                den += t * t;
            }
            host.update(num, den);
            colour = host.colour(colour);
            let (sums, got) = fit.read();
            for c in 0..3 {
                assert!((sums.num[c] - host.num[c]).abs() < 1e-5, "step {step}");
                assert!(
                    (got[c] - colour[c]).abs() < 1e-5,
                    "step {step}: {got:?} vs {colour:?}"
                );
            }
            assert!((sums.den - host.den).abs() < 1e-5);
        }
        assert!(colour.iter().any(|&c| c > 0.1), "the fit moved: {colour:?}");
    }
}
