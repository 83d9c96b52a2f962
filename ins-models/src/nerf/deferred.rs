//! ARF's deferred back-propagation, for stylization patches larger than one render's memory:
//! the patch is rendered once without a graph, the perceptual loss's gradient is taken at its
//! pixels, then its rays are rendered again chunk by chunk, each chunk back-propagating its
//! pixels' share of that gradient. The parameters get the gradient of the loss on the whole
//! patch (each chunk is rendered with the same samples in both passes), at the memory of one
//! chunk's graph: a full-view loss (`--patch 200 --stride 1` on lego) fits where a direct one
//! would hold every sample of the view at once.

use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::prelude::*;

use super::model::NerfModel;
use super::render::{RenderRays, Rendered, Sampling, render};

/// Where and how a patch's rays are rendered for stylization.
#[derive(Clone, Copy)]
pub struct PatchRender<'a> {
    /// The rays, in the patch's row-major order.
    pub rays: &'a RenderRays,
    /// How samples are placed along them.
    pub sampling: Sampling<'a>,
    /// The style codes `[S, n_styles]` the patch is rendered under (on the autodiff device).
    pub codes: &'a Tensor<2>,
    /// Background colour.
    pub background: [f32; 3],
    /// The step's seed (sample jitter).
    pub seed: u64,
    /// Rays per chunk.
    pub chunk: usize,
}

/// The pixels of a patch under every style, `[S·R, 3]` style-major (as one render gives them),
/// and how many samples they took (per style).
pub struct PatchPixels {
    /// Colours.
    pub rgb: Tensor<2>,
    /// Samples evaluated.
    pub samples: usize,
}

impl PatchRender<'_> {
    /// Seed of chunk `c`: the step's own for the first, so a patch of one chunk is rendered
    /// exactly as an unchunked render would be.
    fn chunk_seed(&self, c: usize) -> u64 {
        if c == 0 {
            self.seed
        } else {
            self.seed ^ (c as u64).wrapping_mul(0xA24B_AED4_963E_E407)
        }
    }

    /// Ray ranges of the chunks.
    fn ranges(&self) -> Vec<(usize, usize)> {
        let n = self.rays.len();
        let size = self.chunk.max(1);
        (0..n.div_ceil(size))
            .map(|c| (c * size, ((c + 1) * size).min(n)))
            .collect()
    }

    /// Chunk `c` of the patch rendered by `model` on `device`.
    fn render_chunk(
        &self,
        model: &NerfModel,
        codes: Tensor<2>,
        c: usize,
        (a, b): (usize, usize),
        device: &Device,
    ) -> Rendered {
        render(
            model,
            &self.rays.slice(a, b),
            self.sampling,
            Some(codes),
            self.background,
            Some(self.chunk_seed(c)),
            device,
        )
    }

    /// The patch rendered chunk by chunk by `model` on `device` (with or without a graph,
    /// as they are), the chunks' pixels joined style-major.
    pub fn pixels(&self, model: &NerfModel, codes: Tensor<2>, device: &Device) -> PatchPixels {
        let s = codes.dims()[0];
        let mut rgb = Vec::new();
        let mut samples = 0;
        for (c, range) in self.ranges().into_iter().enumerate() {
            let out = self.render_chunk(model, codes.clone(), c, range, device);
            samples += out.samples;
            let n = range.1 - range.0;
            rgb.push(out.fine.rgb.reshape([s, n, 3]));
        }
        let r = self.rays.len();
        PatchPixels {
            rgb: Tensor::cat(rgb, 1).reshape([s * r, 3]),
            samples,
        }
    }

    /// Deferred back-propagation on `model` (on the autodiff `device`):
    /// 1. the patch rendered without a graph ([`Self::pixels`] of `model.valid()`);
    /// 2. `loss` (of the pixels `[S·R, 3]`, a weighted scalar) and its gradient at the pixels;
    /// 3. each chunk rendered again with a graph and back-propagated with its pixels' share
    ///    of that gradient, plus `extra` of the chunk and of the patch's sample count (a term
    ///    the chunk's samples carry, already weighted for their share; `None`: nothing).
    ///
    /// Returns the parameter gradients, the loss's value and the samples evaluated.
    pub fn backward(
        &self,
        model: &NerfModel,
        device: &Device,
        loss: impl FnOnce(Tensor<2>) -> Tensor<1>,
        mut extra: impl FnMut(&Rendered, usize) -> Option<Tensor<1>>,
    ) -> (GradientsParams, Tensor<1>, usize) {
        let inner_device = device.clone().inner();
        let detached = self.pixels(&model.valid(), self.codes.clone().inner(), &inner_device);
        let pixels = Tensor::from_inner(detached.rgb).require_grad();
        let value = loss(pixels.clone());
        let grads = value.backward();
        let s = self.codes.dims()[0];
        let r = self.rays.len();
        let at_pixels = pixels
            .grad(&grads)
            .map(|g| g.reshape([s, r, 3]))
            .unwrap_or_else(|| Tensor::zeros([s, r, 3], &inner_device));
        let mut accumulated = GradientsAccumulator::<NerfModel>::new();
        for (c, (a, b)) in self.ranges().into_iter().enumerate() {
            let out = self.render_chunk(model, self.codes.clone(), c, (a, b), device);
            let share = Tensor::from_inner(at_pixels.clone().slice([0..s, a..b, 0..3]))
                .reshape([s * (b - a), 3]);
            let mut surrogate = (out.fine.rgb.clone() * share).sum();
            if let Some(t) = extra(&out, detached.samples) {
                surrogate = surrogate + t;
            }
            if surrogate.is_tracked() {
                accumulated.accumulate(
                    model,
                    GradientsParams::from_grads(surrogate.backward(), model),
                );
            }
        }
        (accumulated.grads(), value.detach(), detached.samples)
    }
}

#[cfg(test)]
mod tests {
    use burn::module::{Module, ModuleVisitor, Param};
    use ins_core::render::occupancy::OccupancyGrid;
    use ins_scene::geometry::Vec3;

    use super::*;
    use crate::nerf::early_stop::INVISIBLE_TRANSMITTANCE;
    use crate::nerf::test_models::{dense_kept_density, patch_rays, stylized_model};

    /// The largest difference between two gradients of every parameter, relative to the
    /// largest entry of the first; and how many parameters had a gradient.
    struct Compare<'a> {
        a: &'a GradientsParams,
        b: &'a GradientsParams,
        worst: f32,
        compared: usize,
    }

    impl ModuleVisitor for Compare<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let (Some(a), Some(b)) = (self.a.get::<D>(param.id), self.b.get::<D>(param.id)) else {
                assert!(
                    self.a.get::<D>(param.id).is_none() && self.b.get::<D>(param.id).is_none(),
                    "a parameter with a gradient in one only"
                );
                return;
            };
            let scale = a.clone().abs().max().into_scalar::<f32>().max(1e-12);
            let diff = (a - b).abs().max().into_scalar::<f32>();
            self.worst = self.worst.max(diff / scale);
            self.compared += 1;
        }
    }

    /// [`Compare`]'s worst difference over `model`'s parameters, at least six of which must
    /// have a gradient.
    fn worst_gradient_difference(
        model: &NerfModel,
        a: &GradientsParams,
        b: &GradientsParams,
    ) -> f32 {
        let mut compare = Compare {
            a,
            b,
            worst: 0.0,
            compared: 0,
        };
        model.visit(&mut compare);
        assert!(compare.compared >= 6, "{} parameters", compare.compared);
        compare.worst
    }

    #[test]
    fn shading_until_opaque_gives_the_whole_rays_pixels_and_gradients() {
        let d = Device::flex().autodiff();
        let model = dense_kept_density(stylized_model(7, &d));
        let grid = OccupancyGrid::new(16, Vec3::splat(-1.0), Vec3::splat(1.0), 0.03);
        let rays = patch_rays(8);
        let codes = Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0]], &d);
        let render_with = |until_opaque: Option<f32>| {
            let sampling = Sampling::Occupancy {
                grid: &grid,
                max_per_ray: 96,
                until_opaque,
            };
            let out = render(
                &model,
                &rays,
                sampling,
                Some(codes.clone()),
                [0.2, 0.3, 0.4],
                Some(3),
                &d,
            );
            // Every pixel's gradient 1: no cancellation between rays, so each parameter's
            // gradient differs by at most what the dropped samples carry (under the threshold
            // of each ray's weight) relative to the whole.
            let loss = out.fine.rgb.clone().sum();
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            (out.fine.rgb, out.samples, grads)
        };
        let (all_rgb, all_samples, all_grads) = render_with(None);
        let (kept_rgb, kept_samples, kept_grads) = render_with(Some(1e-4));
        assert!(
            kept_samples * 2 < all_samples,
            "{kept_samples} of {all_samples} samples shaded: the rays did not turn opaque"
        );
        let diff = (all_rgb.clone() - kept_rgb)
            .abs()
            .max()
            .into_scalar::<f32>();
        assert!(diff < 1e-4, "pixels differ by {diff}");
        let worst = worst_gradient_difference(&model, &all_grads, &kept_grads);
        // Measured: 7e-5 at most.
        assert!(worst < 2e-4, "relative difference {worst}");
        // The stylization's threshold: pixels within half an 8-bit level, gradients within
        // the weight it drops.
        let (kept_rgb, fewer, kept_grads) = render_with(Some(INVISIBLE_TRANSMITTANCE));
        assert!(
            fewer < kept_samples,
            "{fewer} against {kept_samples} samples"
        );
        let diff = (all_rgb - kept_rgb).abs().max().into_scalar::<f32>();
        assert!(diff < 1.0 / 510.0, "pixels differ by {diff}");
        let worst = worst_gradient_difference(&model, &all_grads, &kept_grads);
        // Measured: 704 samples shaded, pixels 4.4e-4 apart, gradients 1.5e-3.
        assert!(
            worst < 2.0 * INVISIBLE_TRANSMITTANCE,
            "relative difference {worst}"
        );
    }

    #[test]
    fn deferred_back_propagation_gives_the_direct_gradient() {
        let d = Device::flex().autodiff();
        let model = stylized_model(5, &d);
        let grid = OccupancyGrid::new(16, Vec3::splat(-1.0), Vec3::splat(1.0), 0.03);
        let rays = patch_rays(8);
        let codes = Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0]], &d);
        let target = Tensor::<2>::random([2 * 64, 3], burn::tensor::Distribution::Default, &d);
        // A loss whose gradient depends on the pixels, as the perceptual one's does.
        let loss = |pixels: Tensor<2>| (pixels - target.clone()).powi_scalar(2).sum();
        let patch = PatchRender {
            rays: &rays,
            sampling: Sampling::Occupancy {
                grid: &grid,
                max_per_ray: 96,
                until_opaque: None,
            },
            codes: &codes,
            background: [0.2, 0.3, 0.4],
            seed: 11,
            chunk: 24,
        };
        // Direct: the same chunks rendered with their graphs kept, one backward.
        let direct = patch.pixels(&model, codes.clone(), &d);
        let direct_value = loss(direct.rgb);
        let want = GradientsParams::from_grads(direct_value.clone().backward(), &model);
        let (got, value, samples) = patch.backward(&model, &d, loss, |_, _| None);
        assert_eq!(samples, direct.samples);
        assert!(samples > 64, "the rays sample the box: {samples}");
        let (v, w) = (
            value.into_scalar::<f32>(),
            direct_value.into_scalar::<f32>(),
        );
        assert!((v - w).abs() <= 1e-5 * w.abs(), "{v} vs {w}");
        let worst = worst_gradient_difference(&model, &want, &got);
        assert!(worst < 1e-4, "relative difference {worst}");
    }
}
