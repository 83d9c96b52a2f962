//! Structural similarity (Wang et al. 2004) of two RGB images in [0, 1]: 11×11 Gaussian window
//! (σ = 1.5), constants for a data range of 1, averaged over channels and valid windows — the
//! definition NeRF papers report.

/// SSIM of two `width × height` RGB images (row major, 3 values per pixel).
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize) -> f64 {
    assert_eq!(a.len(), width * height * 3);
    assert_eq!(b.len(), a.len());
    const R: usize = 5;
    if width <= 2 * R || height <= 2 * R {
        return if a == b { 1.0 } else { 0.0 };
    }
    let g: Vec<f64> = {
        let w: Vec<f64> = (0..=2 * R)
            .map(|i| (-((i as f64 - R as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp())
            .collect();
        let s: f64 = w.iter().sum();
        w.into_iter().map(|v| v / s).collect()
    };
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    // Separable Gaussian filtering of a channel-derived image, valid region only.
    let filter = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let (ow, oh) = (width - 2 * R, height - 2 * R);
        let mut rows = vec![0f64; ow * height];
        for y in 0..height {
            for x in 0..ow {
                rows[y * ow + x] = (0..=2 * R).map(|k| g[k] * f(y * width + x + k)).sum();
            }
        }
        let mut out = vec![0f64; ow * oh];
        for y in 0..oh {
            for x in 0..ow {
                out[y * ow + x] = (0..=2 * R).map(|k| g[k] * rows[(y + k) * ow + x]).sum();
            }
        }
        out
    };
    let mut total = 0.0;
    let mut count = 0usize;
    for c in 0..3 {
        let pa = |i: usize| a[i * 3 + c] as f64;
        let pb = |i: usize| b[i * 3 + c] as f64;
        let mu_a = filter(&pa);
        let mu_b = filter(&pb);
        let aa = filter(&|i| pa(i) * pa(i));
        let bb = filter(&|i| pb(i) * pb(i));
        let ab = filter(&|i| pa(i) * pb(i));
        for i in 0..mu_a.len() {
            let (ma, mb) = (mu_a[i], mu_b[i]);
            let va = aa[i] - ma * ma;
            let vb = bb[i] - mb * mb;
            let cov = ab[i] - ma * mb;
            total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1;
        }
    }
    total / count as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize, f: impl Fn(usize, usize, usize) -> f32) -> Vec<f32> {
        let mut v = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    v.push(f(x, y, c));
                }
            }
        }
        v
    }

    #[test]
    fn identical_images_score_one_and_noise_scores_less() {
        let a = image(32, 24, |x, y, c| {
            ((x * 7 + y * 3 + c * 5) % 17) as f32 / 16.0
        });
        assert!((ssim(&a, &a, 32, 24) - 1.0).abs() < 1e-12);
        // Independent noise of ±0.2 per value (a fixed hash, not a pattern of the image).
        let noisy: Vec<f32> = a
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let h = (i as u32).wrapping_mul(2_654_435_761) >> 16;
                (v + (h % 401) as f32 / 1000.0 - 0.2).clamp(0.0, 1.0)
            })
            .collect();
        // scikit-image's structural_similarity(a, b, channel_axis=2, data_range=1,
        // gaussian_weights=True, sigma=1.5, use_sample_covariance=False) gives 0.93847466.
        let s = ssim(&a, &noisy, 32, 24);
        assert!((s - 0.938_474_66).abs() < 1e-6, "{s}");
        // A constant shift of brightness lowers SSIM only through the luminance term.
        let shifted: Vec<f32> = a.iter().map(|v| v * 0.5 + 0.25).collect();
        assert!(ssim(&a, &shifted, 32, 24) < ssim(&a, &a, 32, 24));
    }
}
