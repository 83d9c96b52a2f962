//! Volume compositing (NeRF's quadrature): per-sample densities and colours along rays become a
//! pixel colour, an expected depth and an opacity.
//!
//! Weights use the exclusive transmittance `T_i = exp(−Σ_{j<i} σ_j δ_j)` and
//! `α_i = 1 − exp(−σ_i δ_i)`. Samples come as each ray's run of rows ([`composite_ragged`], a
//! grid NeRF's marched samples) or padded `[R, S]` ([`composite`], every ray as many; padding
//! has `δ = 0` and contributes nothing); both go through one op
//! ([`crate::kernels::composite`]).

use burn::prelude::*;
use burn::tensor::DType;

use crate::kernels::composite::ragged::{ragged_composite_op, ragged_weights_op};

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
/// the op's own walk if asked for (the compositing kernel does not write them).
#[derive(Debug, Clone)]
enum Weights {
    Computed(Box<Tensor<2>>),
    /// The op's inputs: the densities `[S, N]`, the lengths and offsets, the settings.
    Later(Box<WalkInputs>),
}

/// What the op's weights walk reads again, and the shape the weights are given in.
#[derive(Debug, Clone)]
struct WalkInputs {
    sigma: Tensor<2>,
    delta: Tensor<1>,
    offsets: Tensor<1>,
    settings: Tensor<1>,
    shape: [usize; 2],
}

impl Composite {
    /// Per-sample weights without gradient (they choose where to sample next), in the samples'
    /// own layout: `[R, S]` from [`composite`], `[S, N]` from [`composite_ragged`].
    pub fn weights(&self) -> Tensor<2> {
        match &self.weights {
            Weights::Computed(w) => w.as_ref().clone(),
            Weights::Later(walk) => {
                let WalkInputs {
                    sigma,
                    delta,
                    offsets,
                    settings,
                    shape,
                } = walk.as_ref().clone();
                ragged_weights_op(sigma, [delta, offsets], settings).reshape(shape)
            }
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

/// Where each ray's samples are, on the device: ray `r`'s are rows `offsets[r]..offsets[r + 1]`
/// (front to back), sample `k` at distance `t[k]` standing for `delta[k]` of the ray. Rows past
/// the last offset (a bucket's padding) belong to no ray.
#[derive(Debug, Clone)]
pub struct RaySpans {
    /// Distances `[N]`.
    pub t: Tensor<1>,
    /// Lengths `[N]`.
    pub delta: Tensor<1>,
    /// First row of each ray and one past the last, `[R + 1]`, as f32 (exact below 2²⁴).
    pub offsets: Tensor<1>,
}

impl RaySpans {
    /// From the host's `offsets [R + 1]`, `t [N]` and `delta [N]`.
    pub fn upload(offsets: &[u32], t: &[f32], delta: &[f32], device: &Device) -> Self {
        let offsets: Vec<f32> = offsets.iter().map(|&o| o as f32).collect();
        Self {
            t: Tensor::from_floats(t, device),
            delta: Tensor::from_floats(delta, device),
            offsets: Tensor::from_floats(offsets.as_slice(), device),
        }
    }

    /// Number of rays.
    pub fn rays(&self) -> usize {
        self.offsets.dims()[0] - 1
    }
}

/// Composites marched samples without a padded layout: `sigma [S, N]` and `rgb [S, N, 3]` under
/// `S` styles, ray `r`'s samples the rows `spans` gives it; `S·R` rays out (style-major), as
/// [`composite`] gives them for the same samples padded. Each ray stops where the transmittance
/// in front of a sample falls below `stop_below` (0: never): the samples behind get no weight
/// and no gradient, as if the host had kept only those in front
/// ([`MarchedSamples::until_opaque`](super::marched_samples::MarchedSamples::until_opaque)).
/// On Flex and the CubeCL backends ([`crate::kernels::composite::ragged`]). The offsets travel
/// as f32, exact up to 2²⁴ samples a call: renders go in chunks far below that.
pub fn composite_ragged(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    spans: RaySpans,
    background: [f32; 3],
    stop_below: f32,
) -> Composite {
    let shape = sigma.dims();
    composite_runs(sigma, rgb, spans, background, stop_below, shape)
}

/// [`composite_ragged`], its weights given in `weights_shape` (the samples' own layout).
fn composite_runs(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    spans: RaySpans,
    background: [f32; 3],
    stop_below: f32,
    weights_shape: [usize; 2],
) -> Composite {
    let rows = sigma.dims()[0] * spans.rays();
    let [r, g, b] = background;
    let settings = Tensor::<1>::from_floats([r, g, b, stop_below], &sigma.device());
    let RaySpans { t, delta, offsets } = spans;
    let layout = [t, delta.clone(), offsets.clone()];
    let out = ragged_composite_op(sigma.clone(), rgb, layout, settings.clone());
    Composite {
        rgb: out.clone().slice([0..rows, 0..3]),
        depth: out.clone().slice([0..rows, 3..4]).reshape([rows]),
        opacity: out.slice([0..rows, 4..5]).reshape([rows]),
        weights: Weights::Later(Box::new(WalkInputs {
            shape: weights_shape,
            sigma: sigma.detach(),
            delta,
            offsets,
            settings,
        })),
    }
}

/// Composites samples: `sigma [R, S]`, `rgb [R, S, 3]`, `t [R, S]`, `delta [R, S]`; the part of
/// each ray that nothing stops shows `background` (white for NeRF-synthetic scenes, black
/// elsewhere).
///
/// Through [`composite_ragged`]'s op, each ray a run of `S` rows, when the samples are f32 and
/// `t` and `delta` take no gradient (they never do in a render: they are the samples'
/// places); otherwise [`composite_by_ops`].
pub fn composite(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    t: Tensor<2>,
    delta: Tensor<2>,
    background: [f32; 3],
) -> Composite {
    let [r, s] = sigma.dims();
    let dtypes = [sigma.dtype(), rgb.dtype(), t.dtype(), delta.dtype()];
    let f32 = dtypes.iter().all(|d| *d == DType::F32);
    if s == 0 || !f32 || t.is_tracked() || delta.is_tracked() {
        return composite_by_ops(sigma, rgb, t, delta, background);
    }
    let runs: Vec<f32> = (0..=r).map(|i| (i * s) as f32).collect();
    let spans = RaySpans {
        t: t.reshape([r * s]),
        delta: delta.reshape([r * s]),
        offsets: Tensor::from_floats(runs.as_slice(), &sigma.device()),
    };
    composite_runs(
        sigma.reshape([1, r * s]),
        rgb.reshape([1, r * s, 3]),
        spans,
        background,
        0.0,
        [r, s],
    )
}

/// [`composite`] in Burn's ordinary ops (a running sum, exponentials, products, sums), for
/// inputs the op does not take; the reference the op is tested against.
pub fn composite_by_ops(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    t: Tensor<2>,
    delta: Tensor<2>,
    background: [f32; 3],
) -> Composite {
    let r = sigma.dims()[0];
    let bg = Tensor::<1>::from_floats(background, &sigma.device());
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
        weights: Weights::Computed(Box::new(w.detach())),
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

    /// A ragged composite stopped where rays turn opaque is the composite of the samples the
    /// host's `until_opaque` keeps: the same pixels, and gradients only at those samples.
    #[test]
    fn a_stopped_ray_composites_the_samples_the_host_keeps() {
        use crate::render::marched_samples::MarchedSamples;
        let d = Device::flex().autodiff();
        let mut m = MarchedSamples::default();
        let (mut density, mut colour) = (Vec::new(), Vec::new());
        m.offsets.push(0);
        for ray in 0..6 {
            for j in 0..4 + ray {
                density.push(((j * 7 + ray * 3) % 5) as f32 * ray as f32 * 3.0);
                colour.extend([0.1 * j as f32, 0.5, 1.0 - 0.05 * ray as f32]);
                m.ray.push(ray as u32);
                m.t.push(j as f32);
                m.delta.push(0.1 + 0.05 * (j % 3) as f32);
            }
            m.offsets.push(m.t.len() as u32);
        }
        let min_t = 1.0 / 512.0;
        let (kept_m, kept) = m.until_opaque(&density, min_t);
        assert!(
            kept.len() + 10 < m.len(),
            "{} of {} samples kept",
            kept.len(),
            m.len()
        );
        let n = m.len();
        let sigma = Tensor::<1>::from_floats(density.as_slice(), &d).reshape([1, n]);
        let rgb = Tensor::<1>::from_floats(colour.as_slice(), &d).reshape([1, n, 3]);
        let (sigma, rgb) = (sigma.require_grad(), rgb.require_grad());
        let bg = [1.0, 1.0, 1.0];
        let spans = RaySpans::upload(&m.offsets, &m.t, &m.delta, &d);
        let stopped = composite_ragged(sigma.clone(), rgb.clone(), spans, bg, min_t);
        let rows = Tensor::<1, Int>::from_data(
            TensorData::new(
                kept.iter().map(|&k| k as i64).collect::<Vec<_>>(),
                [kept.len()],
            ),
            &d,
        );
        let spans = RaySpans::upload(&kept_m.offsets, &kept_m.t, &kept_m.delta, &d);
        let front = composite_ragged(
            sigma.clone().select(1, rows.clone()),
            rgb.clone().select(1, rows),
            spans,
            bg,
            0.0,
        );
        let worst = |a: Tensor<2>, b: Tensor<2>| (a - b).abs().max().into_scalar::<f32>();
        assert!(
            worst(stopped.rgb.clone(), front.rgb.clone()) < 1e-6,
            "colours"
        );
        let (a, b) = (stopped.opacity.clone(), front.opacity.clone());
        assert!(
            worst(a.clone().reshape([6, 1]), b.reshape([6, 1])) < 1e-6,
            "opacities"
        );
        // The weights (at the samples) stop there too: each ray's sum to its opacity, none
        // behind.
        let host = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
        let (w, opacity) = (host(stopped.weights()), host(a.clone().reshape([1, 6])));
        for (r, run) in m.offsets.windows(2).enumerate() {
            let own = &w[run[0] as usize..run[1] as usize];
            let sum: f32 = own.iter().sum();
            assert!(
                (sum - opacity[r]).abs() < 1e-6,
                "ray {r}'s weights sum to {sum}"
            );
        }
        for (k, w) in w.iter().enumerate() {
            assert!(
                kept.contains(&(k as u32)) || *w == 0.0,
                "sample {k} lies behind"
            );
        }
        let probe = Tensor::<2>::from_floats([[1.0, -2.0, 0.5]; 6], &d);
        let g = (stopped.rgb * probe.clone()).sum().backward();
        let g_front = (front.rgb * probe).sum().backward();
        // The kept samples' composite picked them out of the same densities: its gradient is
        // over all of them, zero behind.
        let (got, want) = (
            host(sigma.grad(&g).unwrap()),
            host(sigma.grad(&g_front).unwrap()),
        );
        for (k, (a, b)) in got.iter().zip(&want).enumerate() {
            assert!(
                (a - b).abs() < 1e-6,
                "density gradient of sample {k}: {a} vs {b}"
            );
            if !kept.contains(&(k as u32)) {
                assert_eq!(*a, 0.0, "sample {k} lies behind");
            }
        }
    }

    /// The ragged composite, and the padded samples through the op as runs of one width,
    /// against the padded samples in ordinary ops: colours, depths, opacities, the weights, and
    /// the gradients of densities and colours, under two styles, with a ray of no samples, one
    /// of one and a dense one.
    #[test]
    fn the_ragged_composite_is_the_padded_one() {
        use burn::tensor::Distribution;
        let d = Device::flex().autodiff();
        d.seed(3);
        let counts = [3usize, 0, 1, 40, 7];
        let (styles, rays, width) = (2, counts.len(), 40);
        let n: usize = counts.iter().sum();
        let mut offsets = vec![0u32];
        let (mut t, mut delta, mut index) = (vec![], vec![], vec![]);
        for (r, &c) in counts.iter().enumerate() {
            for j in 0..c {
                t.push(2.0 + 0.05 * j as f32);
                delta.push(0.03 + 0.01 * (j % 3) as f32);
                index.push((offsets[r] as usize + j) as i64);
            }
            // The padded row: this ray's samples, then padding (n: a zero appended below).
            index.extend(std::iter::repeat_n(n as i64, width - c));
            offsets.push(offsets[r] + c as u32);
        }
        let sigma = Tensor::<2>::random([styles, n], Distribution::Uniform(0.0, 30.0), &d);
        let rgb = Tensor::<3>::random([styles, n, 3], Distribution::Default, &d);
        let (sigma, rgb) = (sigma.require_grad(), rgb.require_grad());
        let probe = Tensor::<2>::random([styles * rays, 5], Distribution::Default, &d);
        let bg = [1.0, 0.5, 0.0];
        let loss = |c: &Composite| {
            let out = Tensor::cat(
                vec![
                    c.rgb.clone(),
                    c.depth.clone().reshape([styles * rays, 1]),
                    c.opacity.clone().reshape([styles * rays, 1]),
                ],
                1,
            );
            (out.clone() * probe.clone()).sum()
        };
        let spans = RaySpans::upload(&offsets, &t, &delta, &d);
        let ragged = composite_ragged(sigma.clone(), rgb.clone(), spans, bg, 0.0);
        // The same samples padded: zero density and spacing past each ray's own.
        let index = Tensor::<1, Int>::from_data(TensorData::new(index, [rays * width]), &d);
        let pad = |x: Tensor<2>| Tensor::cat(vec![x, Tensor::zeros([styles, 1], &d)], 1);
        let host_row = |v: &[f32]| {
            pad(Tensor::<1>::from_floats(v, &d)
                .reshape([1, n])
                .repeat_dim(0, styles))
        };
        let at = |x: Tensor<2>| x.select(1, index.clone()).reshape([styles * rays, width]);
        // Picked anew for each composite: a backward consumes the picks' graph.
        let padded_samples = || {
            let rgb_p = Tensor::cat(vec![rgb.clone(), Tensor::zeros([styles, 1, 3], &d)], 1)
                .select(1, index.clone())
                .reshape([styles * rays, width, 3]);
            let (t, delta) = (at(host_row(&t)), at(host_row(&delta)));
            (at(pad(sigma.clone())), rgb_p, t, delta)
        };
        let (sigma_p, rgb_p, t_p, delta_p) = padded_samples();
        let padded = composite_by_ops(sigma_p, rgb_p, t_p, delta_p, bg);
        // The same padded samples through the op, each ray a run as wide as the widest.
        let (sigma_p, rgb_p, t_p, delta_p) = padded_samples();
        let runs = composite(sigma_p, rgb_p, t_p, delta_p, bg);
        let worst = |a: Tensor<2>, b: Tensor<2>| (a - b).abs().max().into_scalar::<f32>();
        let col = |x: Tensor<1>| x.reshape([styles * rays, 1]);
        assert!(
            worst(ragged.rgb.clone(), padded.rgb.clone()) < 1e-5,
            "colours"
        );
        assert!(
            worst(col(ragged.depth.clone()), col(padded.depth.clone())) < 1e-5,
            "depths"
        );
        assert!(worst(col(ragged.opacity.clone()), col(padded.opacity.clone())) < 1e-5);
        // The ragged weights at the samples, laid out as the padded ones.
        let at_samples = at(pad(ragged.weights()));
        assert!(worst(at_samples, padded.weights()) < 1e-5, "weights");
        assert!(
            worst(runs.weights(), padded.weights()) < 1e-5,
            "weights in runs"
        );
        let flat = |x: Tensor<3>| x.reshape([styles * n, 3]);
        let g_p = loss(&padded).backward();
        for (c, name) in [(&ragged, "ragged"), (&runs, "runs")] {
            assert!(
                worst(c.rgb.clone(), padded.rgb.clone()) < 1e-5,
                "{name} colours"
            );
            let g = loss(c).backward();
            let gs = worst(sigma.grad(&g).unwrap(), sigma.grad(&g_p).unwrap());
            assert!(gs < 1e-5, "{name}: density gradients differ by {gs}");
            let gc = worst(flat(rgb.grad(&g).unwrap()), flat(rgb.grad(&g_p).unwrap()));
            assert!(gc < 1e-5, "{name}: colour gradients differ by {gc}");
        }
    }
}
