//! Compositing each ray's samples as one run of rows, as nerfacc composites packed samples:
//! no padded `[R, width]` layout.
//!
//! A grid NeRF's rays get 1 to ~200 samples (20 on average on lego), so a padded layout held
//! ten times the samples: picking the samples into it and Burn's ordinary ops over it (a
//! running sum, exponentials, products, sums, and their backward; about 25 launches on a GPU)
//! cost about a quarter of a pretraining step on 2 cores. Here one walk a ray forward, two
//! backward, one for the detached weights: a loop per ray on Flex, rays split between threads,
//! and [`super::ragged_cube`]'s kernels on the GPU backends. Samples in a padded layout (the
//! MLP NeRF's, every ray as many) are runs of equal length
//! ([`crate::render::volume::composite`]).
//!
//! Inputs: `sigma [S, N]`, `rgb [S, N, 3]` under `S` styles, each sample's distance `t [N]` and
//! length `delta [N]`, where each ray's samples start `offsets [R + 1]` (f32, exact below
//! 2²⁴; rows past `offsets[R]` are a bucket's padding, read by no ray) and `settings [4]`: the
//! background's colour, then the transmittance below which a ray stops (the samples behind get
//! no weight and no gradient; 0 walks them all).

#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, DType, Dispatch, Flex, Shape, TensorData, TensorMetadata,
    backend_extension,
};
use burn::prelude::*;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;
use rayon::prelude::*;

use super::ragged_cube;

/// Compositing's forward and backward over runs of samples as backend operations (see the
/// module for the inputs).
#[backend_extension(Flex, Cube, Fusion, Autodiff)]
pub trait RaggedCompositeOps: Backend {
    /// `[S·R, 5]` (style-major): each ray's colour (background included), depth and opacity.
    #[fusion(dtype = sigma, shape = Shape::new([sigma[0] * (offsets[0] - 1), OUTPUTS]))]
    fn ragged_composite(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        settings: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// `(∂L/∂sigma, ∂L/∂rgb)` for the upstream gradient `grad [S·R, 5]`.
    #[fusion(meta = |sigma: &TensorSpec, rgb: &TensorSpec, _t: &TensorSpec, _delta: &TensorSpec, _offsets: &TensorSpec, _settings: &TensorSpec, _grad: &TensorSpec| (sigma.clone(), rgb.clone()))]
    fn ragged_composite_backward(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        settings: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// `[S, N]`: each sample's weight `T_k (1 − e^{−σ_k δ_k})` as the forward walks it (0
    /// behind a ray's stop and on rows no ray reads), without gradient: where to sample next.
    #[fusion(dtype = sigma, shape = Shape::new([sigma[0], sigma[1]]))]
    fn ragged_weights(
        sigma: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        settings: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

impl RaggedCompositeOps for CubeBackend {
    fn ragged_composite(
        sigma: CubeTensor,
        rgb: CubeTensor,
        t: CubeTensor,
        delta: CubeTensor,
        offsets: CubeTensor,
        settings: CubeTensor,
    ) -> CubeTensor {
        ragged_cube::forward(sigma, rgb, t, delta, offsets, settings)
    }

    fn ragged_composite_backward(
        sigma: CubeTensor,
        rgb: CubeTensor,
        t: CubeTensor,
        delta: CubeTensor,
        offsets: CubeTensor,
        settings: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        ragged_cube::backward(sigma, rgb, t, delta, offsets, settings, grad)
    }

    fn ragged_weights(
        sigma: CubeTensor,
        delta: CubeTensor,
        offsets: CubeTensor,
        settings: CubeTensor,
    ) -> CubeTensor {
        ragged_cube::weights(sigma, delta, offsets, settings)
    }
}

/// Rays a parallel job composites on Flex.
const RAYS_A_JOB: usize = 256;

/// Values a ray composites to: colour, depth, opacity.
pub const OUTPUTS: usize = 5;

/// What every pass walks, on the host (Flex: no copy where contiguous): the densities, the
/// lengths, where each ray's run starts, the background and the stop.
struct Runs {
    sigma: FlexTensor,
    delta: FlexTensor,
    offsets: Vec<usize>,
    background: [f32; 3],
    stop_below: f32,
}

/// A tensor the op reads, contiguous, after checking it is f32.
fn host_f32(x: FlexTensor, name: &str) -> FlexTensor {
    assert_eq!(x.dtype(), DType::F32, "compositing runs in f32 ({name})");
    x.to_contiguous()
}

impl Runs {
    fn new([sigma, delta, offsets, settings]: [FlexTensor; 4]) -> Self {
        let (sigma, delta) = (host_f32(sigma, "densities"), host_f32(delta, "spacings"));
        let (offsets, settings) = (
            host_f32(offsets, "ray offsets"),
            host_f32(settings, "settings"),
        );
        let settings = settings.as_slice::<f32>().unwrap();
        let offsets: Vec<usize> = offsets
            .as_slice::<f32>()
            .unwrap()
            .iter()
            .map(|&o| o as usize)
            .collect();
        let (s, n) = (sigma.shape(), delta.shape()[0]);
        assert!(s[1] == n, "compositing {s:?} densities, {n} spacings");
        assert!(
            !offsets.is_empty()
                && offsets.windows(2).all(|w| w[0] <= w[1])
                && offsets[offsets.len() - 1] <= n,
            "ray offsets for {n} samples"
        );
        Self {
            sigma,
            delta,
            offsets,
            background: [settings[0], settings[1], settings[2]],
            stop_below: settings[3],
        }
    }

    /// The colours `[S, N, 3]` and distances `[N]` the forward and backward read too.
    fn shading(&self, rgb: FlexTensor, t: FlexTensor) -> (FlexTensor, FlexTensor) {
        let (rgb, t) = (host_f32(rgb, "colours"), host_f32(t, "distances"));
        let (c, n) = (rgb.shape(), self.samples());
        assert!(
            c[0] == self.styles() && c[1] == n && c[2] == 3 && t.shape()[0] == n,
            "compositing {:?} densities, {c:?} colours, {} distances",
            self.sigma.shape(),
            t.shape()[0]
        );
        (rgb, t)
    }

    fn styles(&self) -> usize {
        self.sigma.shape()[0]
    }

    fn rays(&self) -> usize {
        self.offsets.len() - 1
    }

    fn samples(&self) -> usize {
        self.delta.shape()[0]
    }

    /// Ray `r`'s samples under style `style`, front to back until the stop: each sample's row
    /// `k`, the transmittance in front of it `T_k` and its own `e^{−σ_k δ_k}` (its weight is
    /// `T_k (1 − e^{−σ_k δ_k})`).
    fn walk(&self, r: usize, style: usize) -> impl Iterator<Item = (usize, f32, f32)> + '_ {
        let n = self.samples();
        let sigma = &self.sigma.as_slice::<f32>().unwrap()[style * n..][..n];
        let delta = self.delta.as_slice::<f32>().unwrap();
        let mut clear = 1.0f32;
        (self.offsets[r]..self.offsets[r + 1])
            .map(move |k| {
                let through = (-(sigma[k] * delta[k])).exp();
                let front = clear;
                clear *= through;
                (k, front, through)
            })
            .take_while(|&(_, front, _)| front >= self.stop_below)
    }

    /// Each style's and ray's own rows of a `[S, N, width]` output, in order (rows no ray
    /// reads, a bucket's padding, are passed over): `(ray, style, rows)`.
    fn split<'a>(&self, out: &'a mut [f32], width: usize) -> Vec<(usize, usize, &'a mut [f32])> {
        let (styles, rays, n) = (self.styles(), self.rays(), self.samples());
        let mut runs = Vec::with_capacity(styles * rays);
        let (mut rest, mut at) = (out, 0);
        for style in 0..styles {
            for r in 0..rays {
                let first = style * n + self.offsets[r];
                let len = self.offsets[r + 1] - self.offsets[r];
                let (_, tail) = std::mem::take(&mut rest).split_at_mut(width * (first - at));
                let (own, tail) = tail.split_at_mut(width * len);
                (rest, at) = (tail, first + len);
                runs.push((r, style, own));
            }
        }
        runs
    }
}

impl RaggedCompositeOps for Flex {
    fn ragged_composite(
        sigma: FlexTensor,
        rgb: FlexTensor,
        t: FlexTensor,
        delta: FlexTensor,
        offsets: FlexTensor,
        settings: FlexTensor,
    ) -> FlexTensor {
        let h = Runs::new([sigma, delta, offsets, settings]);
        let (rgb, t) = h.shading(rgb, t);
        let (rays, n) = (h.rays(), h.samples());
        let (rgb, t) = (rgb.as_slice::<f32>().unwrap(), t.as_slice::<f32>().unwrap());
        let mut out = vec![0.0f32; h.styles() * rays * OUTPUTS];
        out.par_chunks_mut(RAYS_A_JOB * OUTPUTS)
            .enumerate()
            .for_each(|(job, chunk)| {
                for (i, dst) in chunk.chunks_exact_mut(OUTPUTS).enumerate() {
                    let unit = job * RAYS_A_JOB + i;
                    let (style, r) = (unit / rays, unit % rays);
                    let mut sums = [0.0f32; OUTPUTS];
                    for (k, front, through) in h.walk(r, style) {
                        let (i, w) = (style * n + k, front * (1.0 - through));
                        for (sum, c) in sums.iter_mut().zip(&rgb[3 * i..3 * i + 3]) {
                            *sum += w * c;
                        }
                        sums[3] += w * t[k];
                        sums[4] += w;
                    }
                    for (d, (sum, bg)) in dst.iter_mut().zip(sums.iter().zip(h.background)) {
                        *d = sum + (1.0 - sums[4]) * bg;
                    }
                    dst[3..].copy_from_slice(&sums[3..]);
                }
            });
        FlexTensor::from_data(TensorData::new(out, [h.styles() * rays, OUTPUTS]))
    }

    fn ragged_composite_backward(
        sigma: FlexTensor,
        rgb: FlexTensor,
        t: FlexTensor,
        delta: FlexTensor,
        offsets: FlexTensor,
        settings: FlexTensor,
        grad: FlexTensor,
    ) -> (FlexTensor, FlexTensor) {
        let h = Runs::new([sigma, delta, offsets, settings]);
        let (rgb, t) = h.shading(rgb, t);
        let grad = host_f32(grad, "upstream gradient");
        let grad = grad.as_slice::<f32>().unwrap();
        let (styles, rays, n) = (h.styles(), h.rays(), h.samples());
        let (rgb, t) = (rgb.as_slice::<f32>().unwrap(), t.as_slice::<f32>().unwrap());
        let delta = h.delta.as_slice::<f32>().unwrap();
        let mut g_sigma = vec![0.0f32; styles * n];
        let mut g_rgb = vec![0.0f32; styles * n * 3];
        let runs: Vec<_> = h
            .split(&mut g_sigma, 1)
            .into_iter()
            .zip(h.split(&mut g_rgb, 3))
            .map(|((r, style, gs), (_, _, gc))| (r, style, gs, gc))
            .collect();
        runs.into_par_iter().for_each(|(r, style, gs, gc)| {
            let g = &grad[(style * rays + r) * OUTPUTS..][..OUTPUTS];
            // What a unit of weight is worth against the background, whatever the sample.
            let bg = h.background;
            let base = g[4] - g[0] * bg[0] - g[1] * bg[1] - g[2] * bg[2];
            let worth = |k: usize| {
                let i = style * n + k;
                base + g[0] * rgb[3 * i]
                    + g[1] * rgb[3 * i + 1]
                    + g[2] * rgb[3 * i + 2]
                    + g[3] * t[k]
            };
            // First pass: Σ q_i w_i over the ray.
            let total: f32 = h
                .walk(r, style)
                .map(|(k, front, through)| worth(k) * front * (1.0 - through))
                .sum();
            // Second pass: each sample's gradients, `Σ_{i>k} q_i w_i` as the total less the
            // prefix.
            let mut prefix = 0.0f32;
            for (j, (k, front, through)) in h.walk(r, style).enumerate() {
                let (w, q) = (front * (1.0 - through), worth(k));
                prefix += q * w;
                gs[j] = (q * front * through - (total - prefix)) * delta[k];
                for (d, gi) in gc[3 * j..3 * j + 3].iter_mut().zip(&g[..3]) {
                    *d = gi * w;
                }
            }
        });
        (
            FlexTensor::from_data(TensorData::new(g_sigma, [styles, n])),
            FlexTensor::from_data(TensorData::new(g_rgb, [styles, n, 3])),
        )
    }

    fn ragged_weights(
        sigma: FlexTensor,
        delta: FlexTensor,
        offsets: FlexTensor,
        settings: FlexTensor,
    ) -> FlexTensor {
        let h = Runs::new([sigma, delta, offsets, settings]);
        let (styles, n) = (h.styles(), h.samples());
        let mut out = vec![0.0f32; styles * n];
        h.split(&mut out, 1)
            .into_par_iter()
            .for_each(|(r, style, own)| {
                for ((_, front, through), w) in h.walk(r, style).zip(own) {
                    *w = front * (1.0 - through);
                }
            });
        FlexTensor::from_data(TensorData::new(out, [styles, n]))
    }
}

#[derive(Debug)]
struct RaggedBackward;

/// The inputs the backward walks again: `[σ, c, t, δ, offsets, settings]`.
type Inputs<B> = [FloatTensor<B>; 6];

impl<B: Backend + RaggedCompositeOps> Backward<B, 2> for RaggedBackward {
    type State = Inputs<B>;

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [sigma_node, rgb_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let [sigma, rgb, t, delta, offsets, settings] = ops.state;
        let (grad_sigma, grad_rgb) =
            B::ragged_composite_backward(sigma, rgb, t, delta, offsets, settings, grad);
        if let Some(node) = sigma_node {
            grads.register::<B>(node.id, grad_sigma);
        }
        if let Some(node) = rgb_node {
            grads.register::<B>(node.id, grad_rgb);
        }
    }
}

impl<B: Backend + RaggedCompositeOps, C: CheckpointStrategy> RaggedCompositeOps for Autodiff<B, C> {
    fn ragged_composite(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        settings: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let prep = RaggedBackward
            .prepare::<C>([sigma.node(), rgb.node()])
            .compute_bound()
            .stateful();
        let inputs: Inputs<B> = [
            sigma.into_primitive(),
            rgb.into_primitive(),
            t.into_primitive(),
            delta.into_primitive(),
            offsets.into_primitive(),
            settings.into_primitive(),
        ];
        let forward = |[s, c, t, d, o, x]: Inputs<B>| B::ragged_composite(s, c, t, d, o, x);
        match prep {
            OpsKind::Tracked(prep) => {
                let out = forward(inputs.clone());
                prep.finish(inputs, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward(inputs)),
        }
    }

    fn ragged_composite_backward(
        sigma: FloatTensor<Self>,
        rgb: FloatTensor<Self>,
        t: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        settings: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_sigma, grad_rgb) = B::ragged_composite_backward(
            sigma.into_primitive(),
            rgb.into_primitive(),
            t.into_primitive(),
            delta.into_primitive(),
            offsets.into_primitive(),
            settings.into_primitive(),
            grad.into_primitive(),
        );
        (
            <Self as AutodiffBackend>::from_inner(grad_sigma),
            <Self as AutodiffBackend>::from_inner(grad_rgb),
        )
    }

    fn ragged_weights(
        sigma: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        offsets: FloatTensor<Self>,
        settings: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        <Self as AutodiffBackend>::from_inner(B::ragged_weights(
            sigma.into_primitive(),
            delta.into_primitive(),
            offsets.into_primitive(),
            settings.into_primitive(),
        ))
    }
}

/// `[S·R, 5]` (style-major rays: colour, depth, opacity) through the op (see the module for
/// the inputs), on Flex and the CubeCL backends; gradients reach `sigma` and `rgb`.
pub fn ragged_composite_op(
    sigma: Tensor<2>,
    rgb: Tensor<3>,
    [t, delta, offsets]: [Tensor<1>; 3],
    settings: Tensor<1>,
) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as RaggedCompositeOps>::ragged_composite(
        sigma.into_dispatch(),
        rgb.into_dispatch(),
        t.into_dispatch(),
        delta.into_dispatch(),
        offsets.into_dispatch(),
        settings.into_dispatch(),
    ))
}

/// `[S, N]`: [`ragged_composite_op`]'s weights at each sample (see
/// [`RaggedCompositeOps::ragged_weights`]), detached.
pub fn ragged_weights_op(
    sigma: Tensor<2>,
    [delta, offsets]: [Tensor<1>; 2],
    settings: Tensor<1>,
) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as RaggedCompositeOps>::ragged_weights(
        sigma.detach().into_dispatch(),
        delta.into_dispatch(),
        offsets.into_dispatch(),
        settings.into_dispatch(),
    ))
}
