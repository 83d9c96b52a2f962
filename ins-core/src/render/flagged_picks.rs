//! Up to `k` of the entries a mask flags, chosen on the device: no read-back, and the same
//! shapes every step.
//!
//! Why: choosing on the host means reading the mask back, and on a GPU a read-back in the
//! middle of a step drains the queue and leaves the GPU waiting for the host (issue 48). Here
//! every flagged entry learns its rank among the flagged ones from a running sum, the ranks are
//! scattered into a rank → entry table, and `k` ranks are read from it: all of them when at
//! most `k` are flagged, else one from each of `k` equal strata of the ranks, at an offset drawn
//! on the host. The arithmetic is integer throughout, so every backend picks the same entries.
//! On the GPU backends one kernel does it ([`crate::kernels::ranked_picks`]): each pick finds the
//! entry of its rank by a binary search of the running sum, with no table.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use crate::kernels::cube_f32;
use crate::kernels::ranked_picks::op::ranked_picks_op;

/// The resolution of a pick's place inside its stratum.
const OFFSET_STEPS: i64 = 1024;

/// `k` picks among the entries of `flags [N]` that are 1 (the others 0): their indices `[k]`
/// and weights `[k]`, 1 for a pick and 0 for a filler (index 0) when fewer than `k` are
/// flagged. With `T ≥ k` flagged, pick `i` takes rank `⌊(i·T + ⌊uᵢ·T/1024⌋)/k⌋`, `uᵢ` drawn in
/// `[0, 1024)` by `seed`: one pick in each of `k` equal strata of the ranks, in order. Each
/// product is split (`⌊a·T/b⌋ = a·⌊T/b⌋ + ⌊a·(T mod b)/b⌋`) so that none outgrows 32-bit
/// integers (the device's) for any `N`.
pub fn pick_flagged(flags: Tensor<1>, k: usize, seed: u64) -> (Tensor<1, Int>, Tensor<1>) {
    let [n] = flags.dims();
    assert!(
        (k as u64).pow(2) < 1 << 31,
        "{k} picks: their strata overflow 32-bit integers"
    );
    let device = flags.device();
    let flags = flags.detach();
    let counts = flags.clone().cumsum(0); // [N]: flagged entries up to and including each
    let mut rng = SmallRng::seed_from_u64(seed);
    let u: Vec<i64> = (0..k).map(|_| rng.random_range(0..OFFSET_STEPS)).collect();
    if n < 1 << 24 && cube_f32(&device, &[counts.dtype()]) {
        // One kernel on the GPU backends: the same ranks, each entry found by a binary search
        // of the running count (counts and entries exact in f32 below 2²⁴).
        let offsets: Vec<f32> = u.iter().map(|&o| o as f32).collect();
        let offsets = Tensor::<1>::from_floats(offsets.as_slice(), &device);
        return ranked_picks_op(counts, offsets, OFFSET_STEPS as u32);
    }
    let total = counts.clone().slice([n - 1..n]).int().expand([k]);
    // Rank of each flagged entry; the others go to a spare slot N, adding 0 there.
    let flagged = flags.clone().int();
    let slot = (counts.int().sub_scalar(1) * flagged.clone())
        + flagged.clone().neg().add_scalar(1).mul_scalar(n as i64);
    let entries = Tensor::<1, Int>::arange(0..n as i64, &device) * flagged;
    let table =
        Tensor::<1, Int>::zeros([n + 1], &device).scatter(0, slot, entries, IndexingUpdateOp::Add);
    // ⌊a·T/b⌋ for a < b, without forming a·T.
    let scaled = |a: Tensor<1, Int>, b: i64| {
        a.clone() * total.clone().div_scalar(b)
            + (a * total.clone().remainder_scalar(b)).div_scalar(b)
    };
    let u = Tensor::<1, Int>::from_data(TensorData::new(u, [k]), &device);
    let i = Tensor::<1, Int>::arange(0..k as i64, &device);
    // ⌊(i·T + o)/k⌋ = i·⌊T/k⌋ + ⌊(i·(T mod k) + o)/k⌋, with o = ⌊u·T/1024⌋ < T.
    let offset = scaled(u, OFFSET_STEPS);
    let strata = i.clone() * total.clone().div_scalar(k as i64)
        + (i.clone() * total.clone().remainder_scalar(k as i64) + offset).div_scalar(k as i64);
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
        // The split products give the direct formula's ranks exactly.
        let mut rng = SmallRng::seed_from_u64(11);
        for (i, &j) in index.iter().enumerate() {
            let u = rng.random_range(0..OFFSET_STEPS) as usize;
            assert_eq!(j, ranked[(i * t + u * t / 1024) / k], "pick {i}");
        }
        assert_ne!(pick(&flags, k, 12).0, index);
    }
}
