//! A signed distance field rendered as a volume (NeuS): the opacity of each ray section comes
//! from the SDF through a logistic CDF Φ_s of learnable sharpness `s`,
//! `α = max((Φ_s(f_prev) − Φ_s(f_next)) / Φ_s(f_prev), 0)`, so the compositing weight peaks
//! where the ray crosses the zero level set (unbiased, occlusion-aware), and every sample
//! along the ray, not only the first surface point, gets a colour and a geometry gradient:
//! what lets a concavity open up where sphere tracing with mask supervision fills it.

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

use crate::kernels::cube_f32;
use crate::kernels::section_weights::op::section_weights_op;

/// NeuS's learnable sharpness: `s = exp(10 · variance)` (the logistic density's inverse
/// standard deviation). It grows as the surface settles, narrowing the band around the zero
/// level set that the colour sees.
#[derive(Module, Debug)]
pub struct Sharpness {
    /// `log(s) / 10`, `[1]`.
    pub variance: Param<Tensor<1>>,
}

impl Sharpness {
    /// Starts at `s = exp(10 · variance)` (NeuS and instant-nsr-pl: variance 0.3, s ≈ 20).
    pub fn new(variance: f32, device: &Device) -> Self {
        Self {
            variance: Param::from_tensor(Tensor::from_floats([variance], device)),
        }
    }

    /// `s`, `[1]`, at most 1e6 (clamped in the exponent's range). No floor: a clamp there
    /// stops the gradient, and a sharpness that fell to it early (scan37 through SfM without
    /// masks, the starting sphere mostly over the table, fell to 1 by step 100) never rose again.
    pub fn s(&self) -> Tensor<1> {
        self.variance.val().mul_scalar(10.0).clamp_max(13.8).exp()
    }

    /// `s` on the host (sampling, logs).
    pub fn value(&self) -> f32 {
        self.s()
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .map_or(f32::NAN, |v| v[0])
    }
}

/// Section opacities from the SDF at the sections' ends, NeuS's discrete form (its eq. 13):
/// `α_i = clamp((Φ_s(f_i) − Φ_s(f_{i+1})) / Φ_s(f_i), 0, 1)` for `sdf_ends [R, S + 1]` along each
/// ray and sharpness `s [1]`, `[R, S]`. `live [R, S]` (1 or 0) zeroes padding sections. The
/// ends are the samples themselves, so a long section between two points outside the surface is
/// clear, however long: the renderer can spend its samples near the surface only.
pub fn end_alpha(sdf_ends: Tensor<2>, live: Tensor<2>, s: Tensor<1>) -> Tensor<2> {
    let [r, e] = sdf_ends.dims();
    let cdf = sigmoid(sdf_ends * s.reshape([1, 1]).expand([r, e]));
    let prev = cdf.clone().slice([0..r, 0..e - 1]);
    let next = cdf.slice([0..r, 1..e]);
    ((prev.clone() - next).add_scalar(1e-5) / prev.add_scalar(1e-5)).clamp(0.0, 1.0) * live
}

/// The sections' compositing weights `[R, S]` from the SDF at their ends `sdf_ends [R, S + 1]`,
/// for rays live or not (`live_rays [R]`, 1 or 0) at sharpness `s [1]`:
/// `alpha_weights(end_alpha(..))`, which the GPU backends run as one kernel forward and one
/// backward ([`crate::kernels::section_weights`]).
pub fn section_weights(sdf_ends: Tensor<2>, live_rays: Tensor<1>, s: Tensor<1>) -> Tensor<2> {
    let [r, e] = sdf_ends.dims();
    let dtypes = [sdf_ends.dtype(), live_rays.dtype(), s.dtype()];
    if e > 1 && cube_f32(&sdf_ends.device(), &dtypes) {
        return section_weights_op(sdf_ends, live_rays, s);
    }
    let live = live_rays.reshape([r, 1]).expand([r, e.saturating_sub(1)]);
    alpha_weights(end_alpha(sdf_ends, live, s))
}

/// Compositing weights `wᵢ = αᵢ Πⱼ<ᵢ (1 − αⱼ)` from section opacities `[R, S]` (ordered along
/// each ray).
pub fn alpha_weights(alpha: Tensor<2>) -> Tensor<2> {
    let log_clear = alpha.clone().neg().add_scalar(1.0 + 1e-7).log();
    let inclusive = log_clear.clone().cumsum(1);
    alpha * (inclusive - log_clear).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vec2(t: Tensor<2>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// A ray through the plane `z = 0` head on: `f(t) = 1 − t` at `n + 1` ends over `[0, 2]`,
    /// so the surface is at t = 1. Returns section midpoints and weights.
    fn plane(n: usize, s: f32, d: &Device) -> (Vec<f32>, Vec<f32>) {
        let dt = 2.0 / n as f32;
        let ends: Vec<f32> = (0..=n).map(|i| 1.0 - i as f32 * dt).collect();
        let mids: Vec<f32> = (0..n).map(|i| (i as f32 + 0.5) * dt).collect();
        let alpha = end_alpha(
            Tensor::<1>::from_floats(ends.as_slice(), d).reshape([1, n + 1]),
            Tensor::ones([1, n], d),
            Tensor::from_floats([s], d),
        );
        (mids, vec2(alpha_weights(alpha)))
    }

    #[test]
    fn a_sharp_plane_is_opaque_at_its_crossing() {
        let d = Device::flex();
        let (mids, w) = plane(200, 2000.0, &d);
        let opacity: f32 = w.iter().sum();
        let depth: f32 = w.iter().zip(&mids).map(|(w, t)| w * t).sum();
        assert!((opacity - 1.0).abs() < 1e-3, "opacity {opacity}");
        assert!((depth - 1.0).abs() < 0.01, "depth {depth}");
    }

    #[test]
    fn the_weight_peaks_at_the_surface_whatever_the_sharpness() {
        // NeuS's first-order unbiasedness: for a plane, the weight's maximum sits at the zero
        // crossing even when the density is wide.
        let d = Device::flex();
        for s in [5.0, 20.0, 200.0] {
            let (mids, w) = plane(400, s, &d);
            let peak = (0..w.len()).max_by(|&a, &b| w[a].total_cmp(&w[b])).unwrap();
            assert!(
                (mids[peak] - 1.0).abs() < 0.01,
                "s {s}: peak at {}",
                mids[peak]
            );
        }
    }

    #[test]
    fn long_sections_outside_the_surface_are_clear_and_padding_is_inert() {
        let d = Device::flex();
        // Ends at distances 0.5, 0.4 (a long empty stretch), then across the surface; a padding
        // section inside the object.
        let alpha = vec2(end_alpha(
            Tensor::<2>::from_floats([[0.5, 0.4, -0.1, -0.3]], &d),
            Tensor::<2>::from_floats([[1.0, 1.0, 0.0]], &d),
            Tensor::from_floats([100.0], &d),
        ));
        assert!(alpha[0] < 1e-3, "empty section: {}", alpha[0]);
        assert!(alpha[1] > 0.999, "the crossing: {}", alpha[1]);
        assert_eq!(alpha[2], 0.0);
    }

    #[test]
    fn the_sharpness_is_learnable() {
        let ad = Device::flex().autodiff();
        let sharp = Sharpness::new(0.3, &ad);
        assert!((sharp.value() - 20.09).abs() < 0.05);
        let grads = sharp.s().sum().backward();
        let g = sharp
            .variance
            .val()
            .grad(&grads)
            .unwrap()
            .into_scalar::<f32>();
        assert!((g - 200.9).abs() < 0.5, "ds/dvariance {g}");
        // Below 1 too: no floor that would stop the gradient.
        let low = Sharpness::new(-0.1, &ad);
        assert!((low.value() - 0.3679).abs() < 1e-3);
        let grads = low.s().sum().backward();
        let g = low
            .variance
            .val()
            .grad(&grads)
            .unwrap()
            .into_scalar::<f32>();
        assert!((g - 3.679).abs() < 0.01, "ds/dvariance {g} below s = 1");
    }
}
