//! Order statistics of measured values (camera distances, sparse points' depths), where a
//! few outliers must not decide a frame or a path.

/// The `q`-quantile (`q` in `[0, 1]`) of `sorted` (ascending), interpolated linearly between
/// neighbouring values; 0 for no values.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let x = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, f) = (x.floor() as usize, x.fract());
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] * (1.0 - f) + sorted[j] * f
}

/// [`percentile`] of values in any order.
pub fn percentile_of(mut values: Vec<f64>, q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    percentile(&values, q)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_between_neighbours() {
        let v = [1.0, 2.0, 4.0, 8.0];
        assert_eq!(percentile(&v, 0.0), 1.0);
        assert_eq!(percentile(&v, 1.0), 8.0);
        assert!((percentile(&v, 0.5) - 3.0).abs() < 1e-12);
        assert_eq!(
            percentile_of(vec![8.0, 1.0, 4.0, 2.0], 0.5),
            percentile(&v, 0.5)
        );
        assert_eq!(percentile(&[], 0.5), 0.0);
    }
}
