//! Up to `k` of the entries a mask flags, chosen on the device: no read-back, and the same
//! shapes every step.
//!
//! Why: choosing on the host means reading the mask back, and on a GPU a read-back in the
//! middle of a step drains the queue and leaves the GPU waiting for the host (issue 48). Here
//! every flagged entry learns its rank among the flagged ones from a running sum, the ranks are
//! scattered into a rank → entry table, and `k` ranks are read from it: all of them when at
//! most `k` are flagged, else one from each of `k` equal strata of the ranks, at an offset drawn
//! on the host. The arithmetic is integer throughout, so every backend picks the same entries.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// The resolution of a pick's place inside its stratum.
const OFFSET_STEPS: i64 = 1024;

/// `k` picks among the entries of `flags [N]` that are 1 (the others 0): their indices `[k]`
/// and weights `[k]`, 1 for a pick and 0 for a filler (index 0) when fewer than `k` are
/// flagged. With `T ≥ k` flagged, stratum `i` holds the ranks from `⌊i·T/k⌋` up to
/// `⌊(i+1)·T/k⌋` and pick `i` takes the flagged entry at `uᵢ/1024` of the way through it, `uᵢ`
/// drawn by `seed`: one pick per stratum, in order. The ranks are split as `i·⌊T/k⌋ +
/// ⌊i·(T mod k)/k⌋`, so that no product outgrows 32-bit integers (the device's) for any `N`.
pub fn pick_flagged(flags: Tensor<1>, k: usize, seed: u64) -> (Tensor<1, Int>, Tensor<1>) {
    let [n] = flags.dims();
    assert!(
        (k as u64).pow(2) < 1 << 31,
        "{k} picks: their strata overflow 32-bit integers"
    );
    let device = flags.device();
    let flags = flags.detach();
    let counts = flags.clone().cumsum(0); // [N]: flagged entries up to and including each
    let total = counts.clone().slice([n - 1..n]).int().expand([k]);
    // Rank of each flagged entry; the others go to a spare slot N, adding 0 there.
    let flagged = flags.clone().int();
    let slot = (counts.int().sub_scalar(1) * flagged.clone())
        + flagged.clone().neg().add_scalar(1).mul_scalar(n as i64);
    let entries = Tensor::<1, Int>::arange(0..n as i64, &device) * flagged;
    let table =
        Tensor::<1, Int>::zeros([n + 1], &device).scatter(0, slot, entries, IndexingUpdateOp::Add);
    // Where stratum i starts, ⌊i·T/k⌋, for i = 0 ..= k.
    let share = total.clone().div_scalar(k as i64); // ⌊T/k⌋
    let rest = total.clone().remainder_scalar(k as i64); // T mod k
    let start =
        |i: Tensor<1, Int>| i.clone() * share.clone() + (i * rest.clone()).div_scalar(k as i64);
    let i = Tensor::<1, Int>::arange(0..k as i64, &device);
    let first = start(i.clone());
    let width = start(i.clone().add_scalar(1)) - first.clone();
    let mut rng = SmallRng::seed_from_u64(seed);
    let u: Vec<i64> = (0..k).map(|_| rng.random_range(0..OFFSET_STEPS)).collect();
    let u = Tensor::<1, Int>::from_data(TensorData::new(u, [k]), &device);
    let strata = first + (u * width).div_scalar(OFFSET_STEPS);
    let rank = i
        .clone()
        .mask_where(total.clone().greater_equal_elem(k as i64), strata)
        .clamp(0, n as i64);
    let weight = i.lower(total).float();
    (table.select(0, rank), weight)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pick(flags: &[f32], k: usize, seed: u64) -> (Vec<i64>, Vec<f32>) {
        let d = Device::flex();
        let (index, weight) = pick_flagged(Tensor::<1>::from_floats(flags, &d), k, seed);
        (
            index
                .into_data()
                .convert::<i64>()
                .try_to_vec::<i64>()
                .unwrap(),
            weight.into_data().try_to_vec::<f32>().unwrap(),
        )
    }

    /// At most `k` flagged: each exactly once, weighted 1, then fillers weighted 0.
    #[test]
    fn few_flags_are_all_picked_once() {
        let flags = [0., 1., 0., 0., 1., 1., 0., 1.];
        let (index, weight) = pick(&flags, 6, 3);
        assert_eq!(&index[..4], &[1, 4, 5, 7]);
        assert_eq!(weight, vec![1., 1., 1., 1., 0., 0.]);
        let (index, weight) = pick(&[0.0; 5], 3, 3);
        assert_eq!((index, weight), (vec![0; 3], vec![0.0; 3]));
    }

    /// More than `k` flagged: `k` flagged entries in order, one from each stratum of the
    /// ranks, which move with the seed.
    #[test]
    fn many_flags_are_picked_one_per_stratum() {
        let flags: Vec<f32> = (0..1000).map(|j| ((j * 7) % 3 == 0) as u8 as f32).collect();
        let ranked: Vec<i64> = (0..1000)
            .filter(|&j| flags[j] == 1.0)
            .map(|j| j as i64)
            .collect();
        let k = 50;
        let (index, weight) = pick(&flags, k, 11);
        assert_eq!(weight, vec![1.0; k]);
        let t = ranked.len();
        for (i, &j) in index.iter().enumerate() {
            let rank = ranked
                .iter()
                .position(|&e| e == j)
                .expect("a flagged entry");
            assert!(
                rank * k + k > i * t && rank * k < (i + 1) * t,
                "pick {i}: rank {rank}"
            );
        }
        assert!(index.windows(2).all(|w| w[0] <= w[1]));
        assert_ne!(pick(&flags, k, 12).0, index);
    }
}
