//! Where along each ray the field is evaluated: stratified samples with jitter, and NeRF's
//! hierarchical resampling (inverse CDF of the coarse weights), both on tensors (one kernel
//! each on the GPU backends, [`crate::kernels::samplers`]). The jitter is hashed from a counter
//! ([`crate::kernels::jitter`]), so a step's samples depend only on its seed, and are the same
//! on every backend.

use burn::prelude::*;

use super::merge_rows::merge_rows;
use crate::kernels::cube_f32;
use crate::kernels::jitter::{keys, uniform};
use crate::kernels::samplers::op::{draw_op, stratified_op};

/// `n` uniforms in `[0, 1)` from `seed` (entry `(r, c)` is number `r·cols + c` of the seed's
/// stream), as an `[rows, cols]` tensor.
pub fn uniforms(rows: usize, cols: usize, seed: u64, device: &Device) -> Tensor<2> {
    let keys = keys(seed);
    let v: Vec<f32> = (0..rows * cols).map(|i| uniform(keys, i as u32)).collect();
    Tensor::<1>::from_floats(v.as_slice(), device).reshape([rows, cols])
}

/// Stratified samples: `n` bins between `near [R]` and `far [R]`, one sample per bin, at the
/// bin's centre (`jitter = None`) or at a uniform position inside it. Returns `t [R, n]`.
pub fn stratified(near: Tensor<1>, far: Tensor<1>, n: usize, jitter: Option<u64>) -> Tensor<2> {
    if cube_f32(&near.device(), &[near.dtype(), far.dtype()]) {
        return stratified_op(near.detach(), far.detach(), n, jitter);
    }
    let [r] = near.dims();
    let device = near.device();
    let offsets = match jitter {
        Some(seed) => uniforms(r, n, seed, &device),
        None => Tensor::<2>::full([r, n], 0.5, &device),
    };
    let bins = Tensor::<1, Int>::arange(0..n as i64, &device)
        .float()
        .reshape([1, n]);
    let u = (bins + offsets).div_scalar(n as f32);
    let near = near.reshape([r, 1]);
    let span = far.reshape([r, 1]) - near.clone();
    near + span * u
}

/// Spacings between consecutive samples `t [R, S]`, the last one up to `far [R]`.
pub fn deltas(t: Tensor<2>, far: Tensor<1>) -> Tensor<2> {
    let [r, s] = t.dims();
    let next = Tensor::cat(vec![t.clone().slice([0..r, 1..s]), far.reshape([r, 1])], 1);
    (next - t).clamp_min(0.0)
}

/// NeRF's hierarchical sampling: `n` new distances drawn from the piecewise-constant density
/// that the coarse `weights [R, S]` put on the bins between the midpoints of `t [R, S]`
/// (stratified in CDF space with jitter from `seed`, or at bin centres when `None`), merged with
/// the coarse samples and sorted: `[R, S + n]`. No gradient flows through the result.
pub fn hierarchical(t: Tensor<2>, weights: Tensor<2>, n: usize, seed: Option<u64>) -> Tensor<2> {
    let fine = draw_from_weights(t.clone(), weights, n, seed);
    merge_rows(t.detach(), fine)
}

/// The `n` new distances of [`hierarchical`] alone, in increasing order: `[R, n]`.
pub fn draw_from_weights(
    t: Tensor<2>,
    weights: Tensor<2>,
    n: usize,
    seed: Option<u64>,
) -> Tensor<2> {
    let [r, s] = t.dims();
    let device = t.device();
    let t = t.detach();
    if s >= 3 && cube_f32(&device, &[t.dtype(), weights.dtype()]) {
        return draw_op(t, weights.detach(), n, seed);
    }
    let u = match seed {
        Some(seed) => uniforms(r, n, seed, &device),
        None => Tensor::<2>::full([r, n], 0.5, &device),
    };
    // Bin edges: midpoints between samples; the weights of the inner samples give the pdf.
    let mids = (t.clone().slice([0..r, 1..s]) + t.clone().slice([0..r, 0..s - 1])).mul_scalar(0.5);
    let w = weights.detach().slice([0..r, 1..s - 1]).add_scalar(1e-5);
    let pdf = w.clone() / w.sum_dim(1);
    let cdf = Tensor::cat(vec![Tensor::zeros([r, 1], &device), pdf.cumsum(1)], 1); // [R, s-1]
    let edges = s - 1;
    let bins = Tensor::<1, Int>::arange(0..n as i64, &device)
        .float()
        .reshape([1, n]);
    let u = (bins + u).div_scalar(n as f32).clamp(0.0, 1.0 - 1e-6);
    // Index of the CDF bin each u falls in: count of edges with cdf ≤ u, minus one.
    let below = u
        .clone()
        .unsqueeze_dim::<3>(2)
        .greater_equal(cdf.clone().unsqueeze_dim::<3>(1))
        .int()
        .sum_dim(2)
        .reshape([r, n])
        .sub_scalar(1)
        .clamp(0, edges as i64 - 2);
    let above = below.clone().add_scalar(1);
    let c0 = cdf.clone().gather(1, below.clone());
    let c1 = cdf.gather(1, above.clone());
    let b0 = mids.clone().gather(1, below);
    let b1 = mids.gather(1, above);
    let span = (c1 - c0.clone()).clamp_min(1e-8);
    let frac = ((u - c0) / span).clamp(0.0, 1.0);
    b0.clone() + frac * (b1 - b0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vec2(t: Tensor<2>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn stratified_samples_cover_their_bins_in_order() {
        let d = Device::flex();
        let near = Tensor::<1>::from_floats([2.0, 0.0], &d);
        let far = Tensor::<1>::from_floats([6.0, 1.0], &d);
        let t = vec2(stratified(near.clone(), far.clone(), 8, Some(3)));
        for r in 0..2 {
            let (lo, hi) = if r == 0 { (2.0, 6.0) } else { (0.0, 1.0) };
            let bin = (hi - lo) / 8.0;
            for i in 0..8 {
                let v = t[r * 8 + i];
                assert!(
                    v >= lo + i as f32 * bin && v < lo + (i + 1) as f32 * bin,
                    "{v}"
                );
            }
        }
        let centres = vec2(stratified(near, far, 4, None));
        assert_eq!(&centres[..4], &[2.5, 3.5, 4.5, 5.5]);
    }

    #[test]
    fn hierarchical_samples_follow_the_weights() {
        let d = Device::flex();
        // 64 coarse samples on [0, 64); all weight on samples 40..44: new samples must land
        // between the midpoints around them, [39.5, 43.5].
        let s = 64;
        let t: Vec<f32> = (0..s).map(|i| i as f32).collect();
        let w: Vec<f32> = (0..s)
            .map(|i| if (40..44).contains(&i) { 1.0 } else { 0.0 })
            .collect();
        let t = Tensor::<1>::from_floats(t.as_slice(), &d).reshape([1, s]);
        let w = Tensor::<1>::from_floats(w.as_slice(), &d).reshape([1, s]);
        let all = vec2(hierarchical(t, w, 1000, Some(5)));
        assert_eq!(all.len(), 1064);
        assert!(all.windows(2).all(|p| p[0] <= p[1]), "not sorted");
        // Coarse samples are kept; the 1000 new ones fall inside the weighted region except
        // for the 1e-5 floor's share (≈ 60·1e-5/4 of the mass).
        let inside = all.iter().filter(|&&v| (39.5..=43.5).contains(&v)).count();
        assert!(
            inside >= 1000 + 4 - 2,
            "{inside} samples in the weighted bins"
        );
    }

    #[test]
    fn hierarchical_matches_a_known_cdf() {
        let d = Device::flex();
        // Two inner bins with weights 1 and 3 → a quarter of the samples in the first.
        let t = Tensor::<2>::from_floats([[0.0, 1.0, 2.0, 3.0]], &d);
        let w = Tensor::<2>::from_floats([[0.0, 1.0, 3.0, 0.0]], &d);
        let all = vec2(hierarchical(t, w, 400, None));
        let fine_in_first = all.iter().filter(|&&v| v > 0.5 && v < 1.5).count() - 1;
        assert!((fine_in_first as i64 - 100).abs() <= 2, "{fine_in_first}");
    }
}
