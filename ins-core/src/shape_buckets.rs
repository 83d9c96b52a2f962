//! Tensor sizes rounded up to a few buckets, so GPU kernels are compiled once and reused.
//!
//! Why: on the CubeCL backends (wgpu) kernels are compiled, and matmuls tuned, for the sizes
//! they meet, while a NeRF step's sizes change every step (the rays an occupancy grid lets
//! through, the samples each ray keeps). On an H100 the lego pretrain then spent about 500 ms a
//! step, where a step whose sizes had been seen before took 35 ms. Rounding each size up to one
//! of eight values per octave (at most 12.5 % more) makes sizes repeat; the padding is inert
//! (samples no ray reads, columns of zero density). The CPU backends run no compiler, so they
//! keep the exact sizes and pay nothing.

use burn::backend::DispatchDevice;
use burn::prelude::*;

/// The smallest size ≥ `n` of the form `m · 2^k` with `8 ≤ m < 16` (any `n ≤ 16` becomes 16):
/// eight sizes per octave, at most 12.5 % above `n`, divisible by a large power of two.
pub fn bucket(n: usize) -> usize {
    if n <= 16 {
        return 16;
    }
    let k = (usize::BITS - 1 - n.leading_zeros()) - 3;
    n.div_ceil(1 << k) << k
}

/// The bucket nearest to `n` (below or above): for a count that may move either way, such as
/// a batch's rays, so the work per step stays what was asked for on average.
pub fn nearest_bucket(n: usize) -> usize {
    let up = bucket(n);
    if n <= 16 || up == n {
        return up;
    }
    let k = (usize::BITS - 1 - n.leading_zeros()) - 3;
    let down = (n >> k) << k;
    if n - down <= up - n { down } else { up }
}

/// Whether `device` compiles kernels per size (the CubeCL backends: wgpu), where rounding sizes
/// up to [`bucket`]s pays; the CPU backend (flex) answers no.
pub fn compiles_per_size(device: &Device) -> bool {
    !matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Flex(_)
    )
}

/// `n` rounded up to its [`bucket`] where `device` [compiles per size](compiles_per_size),
/// else `n` itself.
pub fn padded_size(n: usize, device: &Device) -> usize {
    if compiles_per_size(device) {
        bucket(n)
    } else {
        n
    }
}

/// Pads row-major `values` (rows of `width`) to `rows` rows by repeating the first row: the
/// inert filler of a bucketed batch (its rows are evaluated and never read).
pub fn pad_rows<T: Clone>(values: &mut Vec<T>, width: usize, rows: usize) {
    let have = values.len() / width;
    values.reserve(rows.saturating_sub(have) * width);
    for _ in have..rows {
        values.extend_from_within(..width);
    }
}

/// The sum of the first `counted` entries of `values [N]`, the rest being a bucketed batch's
/// padding: masked out (the shape stays the bucket's) when there is padding, a plain sum when
/// there is none (the CPU backend's exact sizes).
pub fn sum_counted(values: Tensor<1>, counted: usize) -> Tensor<1> {
    let [n] = values.dims();
    if counted >= n {
        return values.sum();
    }
    let keep: Vec<f32> = (0..n)
        .map(|i| if i < counted { 1.0 } else { 0.0 })
        .collect();
    let keep = Tensor::<1>::from_floats(keep.as_slice(), &values.device());
    (values * keep).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_counted_sum_leaves_the_padding_out_of_value_and_gradient() {
        let d = Device::flex().autodiff();
        let v = Tensor::<1>::from_floats([1.0, 2.0, 4.0, 8.0], &d).require_grad();
        let padded = sum_counted(v.clone(), 2);
        assert_eq!(padded.clone().into_scalar::<f32>(), 3.0);
        let g = v.grad(&padded.backward()).unwrap().into_data();
        assert_eq!(g.try_to_vec::<f32>().unwrap(), vec![1.0, 1.0, 0.0, 0.0]);
        assert_eq!(sum_counted(v, 4).into_scalar::<f32>(), 15.0);
    }

    #[test]
    fn buckets_cover_every_size_within_an_eighth_and_are_few_per_octave() {
        let mut seen = std::collections::BTreeSet::new();
        for n in 1..=70_000usize {
            let b = bucket(n);
            assert!(b >= n, "bucket({n}) = {b}");
            if n > 16 {
                assert!(
                    (b - n) as f64 <= 0.125 * n as f64,
                    "bucket({n}) = {b} pads more than 12.5 %"
                );
            }
            assert_eq!(bucket(b), b, "a bucket is its own bucket");
            seen.insert(b);
        }
        // 16 ..= 2^16 is 12 octaves of 8 sizes, plus 2^16's successor for 65537..70000.
        assert_eq!(seen.len(), 12 * 8 + 1 + 1, "{seen:?}");
        assert_eq!(bucket(5049), 5120);
        assert_eq!(bucket(5120), 5120);
        assert_eq!(bucket(5121), 5632);
    }

    #[test]
    fn the_nearest_bucket_is_a_bucket_and_no_other_is_closer() {
        for n in 17..=20_000usize {
            let b = nearest_bucket(n);
            assert_eq!(bucket(b), b, "nearest_bucket({n}) = {b} is not a bucket");
            let above = bucket(n);
            let below = (17..=n).rev().find(|&m| bucket(m) == m).unwrap_or(16);
            assert_eq!(
                b.abs_diff(n),
                above.abs_diff(n).min(below.abs_diff(n)),
                "n = {n}"
            );
        }
        assert_eq!(nearest_bucket(5049), 5120);
        assert_eq!(nearest_bucket(4650), 4608);
    }

    #[test]
    fn padding_repeats_the_first_row_up_to_the_count() {
        let mut v = vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        pad_rows(&mut v, 3, 2);
        assert_eq!(v.len(), 6, "already that many rows");
        pad_rows(&mut v, 3, 4);
        assert_eq!(
            v,
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 1.0, 2.0, 3.0, 1.0, 2.0, 3.0]
        );
    }

    #[test]
    fn only_devices_that_compile_per_size_pad() {
        let flex = Device::flex();
        assert!(!compiles_per_size(&flex));
        assert_eq!(padded_size(5049, &flex), 5049);
    }
}
