//! Volume compositing (NeRF's quadrature): per-sample densities and colours along rays become a
//! pixel colour, an expected depth and an opacity.
//!
//! Samples come as a padded `[R, S]` layout: ray `r`'s samples fill the first columns of row
//! `r`, in increasing `t`, and padding columns have `δ = 0`, so they contribute nothing.
//! Weights use the exclusive transmittance `T_i = exp(−Σ_{j<i} σ_j δ_j)` and
//! `α_i = 1 − exp(−σ_i δ_i)`; everything is differentiable (cumsum included).

use burn::prelude::*;

use crate::kernels::composite::op::{composite_op, weights_op};
use crate::kernels::cube_f32;

/// What compositing gives per ray.
#[derive(Debug, Clone)]
pub struct Composite {
    /// Colour `[R, 3]`, background included.
    pub rgb: Tensor<2>,
    /// Expected ray distance `Σ wᵢ tᵢ`, `[R]` (not divided by the opacity).
    pub depth: Tensor<1>,
    /// Opacity `Σ wᵢ`, `[R]`.
    pub opacity: Tensor<1>,
    weights: Weights,
}

/// A composite's per-sample weights, detached: computed on the way (ordinary ops), or left to
/// compute from the densities and spacings if asked for (the compositing kernel does not write
/// them; a kernel of their own does, in one launch).
#[derive(Debug, Clone)]
enum Weights {
    Computed(Tensor<2>),
    Later { sigma: Tensor<2>, delta: Tensor<2> },
}

impl Composite {
    /// Per-sample weights `[R, S]`, without gradient: they choose where to sample next.
    pub fn weights(&self) -> Tensor<2> {
        match &self.weights {
            Weights::Computed(w) => w.clone(),
            Weights::Later { sigma, delta } => weights_op(sigma.clone(), delta.clone()),
        }
    }
}

/// Per-sample compositing weights from densities `sigma [R, S]` (≥ 0) and spacings `delta [R, S]`.
pub fn weights(sigma: Tensor<2>, delta: Tensor<2>) -> Tensor<2> {
    let tau = sigma * delta;
    let inclusive = tau.clone().cumsum(1);
    let transmittance = (tau.clone() - inclusive).exp();
    let alpha = tau.neg().exp().neg().add_scalar(1.0);
    transmittance * alpha
}

/// 1 for the samples whose transmittance in front of them is at least `min_transmittance`, 0
/// for those behind, `[R, S]`, under densities `sigma [R, S]` and spacings `delta [R, S]`: the
/// samples [`MarchedSamples::until_opaque`](super::marched_samples::MarchedSamples::until_opaque)
/// keeps, found on the device. Multiplying the densities by it gives the render of the kept
/// samples alone, without reading the densities back. No gradient flows through it.
pub fn in_front_of_opaque(sigma: Tensor<2>, delta: Tensor<2>, min_transmittance: f32) -> Tensor<2> {
    let tau = sigma.detach().clamp_min(0.0) * delta.detach();
    let in_front = tau.clone().cumsum(1) - tau;
    in_front.lower_equal_elem(-min_transmittance.ln()).float()
}

/// Composites samples: `sigma [R, S]`, `rgb [R, S, 3]`, `t [R, S]`, `delta [R, S]`; the part of
/// each ray that nothing stops shows `background` (white for NeRF-synthetic scenes, black
/// elsewhere).
///
/// On the GPU backends this is one kernel forward and one backward
/// ([`crate::kernels::composite`]) when `t` and `delta` take no gradient (they never do in a
/// render: they are the samples' places); elsewhere, ordinary ops.
pub fn composite(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    t: Tensor<2>,
    delta: Tensor<2>,
    background: [f32; 3],
) -> Composite {
    let [r, s] = sigma.dims();
    let device = sigma.device();
    let bg = Tensor::<1>::from_floats(background, &device);
    let dtypes = [sigma.dtype(), rgb.dtype(), t.dtype(), delta.dtype()];
    if s > 0 && cube_f32(&device, &dtypes) && !t.is_tracked() && !delta.is_tracked() {
        let out = composite_op(sigma.clone(), rgb, t, delta.clone(), bg);
        return Composite {
            rgb: out.clone().slice([0..r, 0..3]),
            depth: out.clone().slice([0..r, 3..4]).reshape([r]),
            opacity: out.slice([0..r, 4..5]).reshape([r]),
            weights: Weights::Later {
                sigma: sigma.detach(),
                delta: delta.detach(),
            },
        };
    }
    let w = weights(sigma, delta);
    let colour: Tensor<2> = (w.clone().unsqueeze_dim::<3>(2) * rgb)
        .sum_dim(1)
        .reshape([r, 3]);
    let opacity: Tensor<1> = w.clone().sum_dim(1).reshape([r]);
    let depth: Tensor<1> = (w.clone() * t).sum_dim(1).reshape([r]);
    let rest = opacity.clone().neg().add_scalar(1.0).reshape([r, 1]);
    Composite {
        rgb: colour + rest * bg.reshape([1, 3]),
        depth,
        opacity,
        weights: Weights::Computed(w.detach()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(values: &[f32], device: &Device) -> Tensor<2> {
        Tensor::<1>::from_floats(values, device).reshape([1, values.len()])
    }

    #[test]
    fn an_opaque_slab_gives_its_depth_and_colour() {
        let d = Device::flex();
        // 100 samples over [2, 6], 0.04 apart; the slab fills [3.5, 4.0) with density 1e4, so
        // the first sample inside it is the one at 3.52.
        let n = 100;
        let dt = 4.0 / n as f32;
        let t: Vec<f32> = (0..n).map(|i| 2.0 + i as f32 * dt).collect();
        let sigma: Vec<f32> = t
            .iter()
            .map(|&x| if (3.5..4.0).contains(&x) { 1e4 } else { 0.0 })
            .collect();
        let mut rgb = Vec::new();
        for &x in &t {
            rgb.extend(if x < 4.0 {
                [0.2, 0.4, 0.8]
            } else {
                [1.0, 0.0, 0.0]
            });
        }
        let c = composite(
            row(&sigma, &d),
            Tensor::<1>::from_floats(rgb.as_slice(), &d).reshape([1, n, 3]),
            row(&t, &d),
            row(&vec![dt; n], &d),
            [1.0, 1.0, 1.0],
        );
        let depth = c.depth.into_scalar::<f32>();
        let opacity = c.opacity.into_scalar::<f32>();
        let colour = c.rgb.into_data().try_to_vec::<f32>().unwrap();
        assert!((opacity - 1.0).abs() < 1e-5, "opacity {opacity}");
        assert!((depth - 3.52).abs() < 1e-3, "depth {depth}");
        for (got, want) in colour.iter().zip([0.2, 0.4, 0.8]) {
            assert!((got - want).abs() < 1e-4, "{colour:?}");
        }
    }

    #[test]
    fn empty_rays_show_the_background_and_padding_is_inert() {
        let d = Device::flex();
        let c = composite(
            row(&[0.0, 0.0, 5.0], &d),
            Tensor::<3>::ones([1, 3, 3], &d).mul_scalar(0.3),
            row(&[1.0, 2.0, 3.0], &d),
            // The third sample is padding: δ = 0, so its density does not count.
            row(&[1.0, 1.0, 0.0], &d),
            [0.0, 0.0, 1.0],
        );
        assert_eq!(
            c.rgb.into_data().try_to_vec::<f32>().unwrap(),
            [0.0, 0.0, 1.0]
        );
        assert_eq!(c.opacity.into_scalar::<f32>(), 0.0);
    }

    #[test]
    fn weights_match_the_closed_form() {
        let d = Device::flex();
        let sigma = [0.5f32, 2.0, 1.0];
        let delta = [0.3f32, 0.2, 0.4];
        let w = weights(row(&sigma, &d), row(&delta, &d))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let mut acc = 0.0f32;
        for i in 0..3 {
            let want = (-acc).exp() * (1.0 - (-sigma[i] * delta[i]).exp());
            assert!((w[i] - want).abs() < 1e-6);
            acc += sigma[i] * delta[i];
        }
    }

    /// The mask keeps exactly the samples the host's `until_opaque` keeps.
    #[test]
    fn the_samples_in_front_of_opaque_are_those_the_host_keeps() {
        use crate::render::marched_samples::MarchedSamples;
        let d = Device::flex();
        let (r, w) = (6, 12);
        let mut m = MarchedSamples::default();
        let (mut sigma, mut delta) = (vec![0f32; r * w], vec![0f32; r * w]);
        let mut density = Vec::new();
        m.offsets.push(0);
        for ray in 0..r {
            let len = 4 + ray; // the rest of the row is padding (δ = 0)
            for j in 0..len {
                let s = ((j * 7 + ray * 3) % 5) as f32 * ray as f32;
                let dt = 0.1 + 0.05 * (j % 3) as f32;
                sigma[ray * w + j] = s;
                delta[ray * w + j] = dt;
                density.push(s);
                m.ray.push(ray as u32);
                m.t.push(j as f32);
                m.delta.push(dt);
            }
            m.offsets.push(m.t.len() as u32);
        }
        let min_t = 1.0 / 512.0;
        let (_, kept) = m.until_opaque(&density, min_t);
        let mask = in_front_of_opaque(
            row(&sigma, &d).reshape([r, w]),
            row(&delta, &d).reshape([r, w]),
            min_t,
        )
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
        let mut want = vec![0f32; r * w];
        for k in kept {
            let k = k as usize;
            let ray = m.ray[k] as usize;
            want[ray * w + (k - m.offsets[ray] as usize)] = 1.0;
        }
        for ray in 0..r {
            let len = 4 + ray;
            assert_eq!(
                &mask[ray * w..ray * w + len],
                &want[ray * w..ray * w + len],
                "ray {ray}"
            );
        }
        assert!(
            want.iter().sum::<f32>() < (r * 4 + 15) as f32,
            "some samples lie behind"
        );
    }
}
