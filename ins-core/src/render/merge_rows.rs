//! Two sets of ray samples, each sorted along its rays, merged without leaving the device.
//! Burn's CubeCL backends (wgpu, CUDA) have no sort kernel: `sort` reads the tensor back, sorts
//! it on the host and uploads the result, a round trip that drains the GPU's queue twice a step
//! in IDR's volume and once in NeRF's hierarchical sampling. What those steps sort is always two
//! sorted sets (the coarse samples and the ones drawn from their weights), so each value's place
//! can be counted: its place in its own set plus the values of the other set before it. One
//! comparison of every `a` with every `b` gives both counts, `Ka·Kb` a row, where counting
//! places in the joined row took `(Ka + Kb)²` (4.5 times as many for NeRF's 64 + 128). On Flex,
//! whose sort runs in place on the host, the plain sort stays.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::kernels::flex::on_flex;

/// `a [R, Ka]` and `b [R, Kb]`, each sorted ascending along its rows, as one sorted row each:
/// `[R, Ka + Kb]`, equal values from `a` first.
pub fn merge_rows(a: Tensor<2>, b: Tensor<2>) -> Tensor<2> {
    let joined = Tensor::cat(vec![a.clone(), b.clone()], 1);
    if on_flex(&joined) {
        return joined.sort(1);
    }
    let rank = merge_ranks(&a.detach(), &b.detach(), MAX_COMPARISONS);
    to_ranks(joined.detach(), rank)
}

/// [`merge_rows`] with each merged value's column in `[a, b]` joined (`[R, Ka + Kb]`, for
/// gathering what goes with the values).
pub fn merge_rows_with_indices(a: Tensor<2>, b: Tensor<2>) -> (Tensor<2>, Tensor<2, Int>) {
    let joined = Tensor::cat(vec![a.clone(), b.clone()], 1);
    if on_flex(&joined) {
        joined.sort_with_indices(1)
    } else {
        by_rank(a.detach(), b.detach(), MAX_COMPARISONS)
    }
}

/// The device path of [`merge_rows_with_indices`]: the values moved to their
/// [`merge_ranks`], and each place's column in `[a, b]`.
fn by_rank(a: Tensor<2>, b: Tensor<2>, max_comparisons: usize) -> (Tensor<2>, Tensor<2, Int>) {
    let rank = merge_ranks(&a, &b, max_comparisons);
    let joined = Tensor::cat(vec![a, b], 1);
    let [r, k] = joined.dims();
    let columns = Tensor::<1, Int>::arange(0..k as i64, &joined.device())
        .reshape([1, k])
        .expand([r, k]);
    let order = Tensor::<2, Int>::zeros([r, k], &joined.device()).scatter(
        1,
        rank.clone(),
        columns,
        IndexingUpdateOp::Add,
    );
    (to_ranks(joined, rank), order)
}

/// The most comparisons [`merge_ranks`] holds at once (16 MB of 32-bit counts): a NeRF
/// render's 8192 rays of 64 + 128 samples are ranked in 16 blocks of rows, not in one buffer
/// some adapters could not even allocate.
const MAX_COMPARISONS: usize = 1 << 22;

/// Each value's place in the merged row `[R, Ka + Kb]` (`a`'s columns, then `b`'s), counted a
/// block of rows of at most `max_comparisons` at a time. NaNs have no place; rows must not hold
/// any.
fn merge_ranks(a: &Tensor<2>, b: &Tensor<2>, max_comparisons: usize) -> Tensor<2, Int> {
    let ([r, ka], [_, kb]) = (a.dims(), b.dims());
    // Column c of the joined row: a's c, or b's c − ka.
    let column = Tensor::<1, Int>::arange(0..(ka + kb) as i64, &a.device()).reshape([1, ka + kb]);
    let block = (max_comparisons / (ka * kb).max(1)).max(1);
    if r <= block {
        return block_ranks(a.clone(), b.clone(), column);
    }
    let blocks = (0..r)
        .step_by(block)
        .map(|start| {
            let rows = start..(start + block).min(r);
            block_ranks(
                a.clone().slice([rows.clone(), 0..ka]),
                b.clone().slice([rows, 0..kb]),
                column.clone(),
            )
        })
        .collect();
    Tensor::cat(blocks, 0)
}

/// [`merge_ranks`] of rows that fit in one block (`column`, `[1, Ka + Kb]`: 0, 1, 2, …):
/// `a_i` goes after the `a`s before it and the `b`s below it, `b_j` after the `b`s before it
/// and the `a`s at or below it.
fn block_ranks(a: Tensor<2>, b: Tensor<2>, column: Tensor<2, Int>) -> Tensor<2, Int> {
    let ([r, ka], [_, kb]) = (a.dims(), b.dims());
    // [R, Ka, 1] against [R, 1, Kb]: entry (i, j) says a_i comes before b_j.
    let before = a
        .unsqueeze_dim::<3>(2)
        .lower_equal(b.unsqueeze_dim::<3>(1))
        .int();
    // a_i: i + (Kb − the b's it comes before); b_j: (j + Ka) + (the a's before it) − Ka.
    let b_below = before
        .clone()
        .sum_dim(2)
        .reshape([r, ka])
        .neg()
        .add_scalar(kb as i64);
    let a_before = before.sum_dim(1).reshape([r, kb]).sub_scalar(ka as i64);
    Tensor::cat(vec![b_below, a_before], 1) + column
}

/// The values of `x [R, K]` moved to their places `rank [R, K]` along each row.
fn to_ranks(x: Tensor<2>, rank: Tensor<2, Int>) -> Tensor<2> {
    Tensor::<2>::zeros(x.dims(), &x.device()).scatter(1, rank, x, IndexingUpdateOp::Add)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn floats(t: Tensor<2>) -> Vec<f32> {
        t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
    }

    fn ints(t: Tensor<2, Int>) -> Vec<i64> {
        t.into_data().convert::<i64>().try_to_vec::<i64>().unwrap()
    }

    /// Sorted rows of different widths with ties inside each set and across them, negative
    /// values, one set wholly below the other and wholly above: the counted places give the
    /// host's sort of the joined rows exactly, in one block and in blocks of two rows and one,
    /// and each index points at its value, equal values keeping their columns' order.
    #[test]
    fn counted_places_merge_rows_as_the_host_sort_does() {
        let d = Device::flex();
        let a_rows: [[f32; 5]; 4] = [
            [-1.0, 0.5, 0.5, 2.0, 3.0],
            [1.0, 2.0, 3.0, 4.0, 5.0],
            [10.0, 11.0, 12.0, 13.0, 14.0],
            [2.0, 2.0, 2.0, 2.0, 2.0],
        ];
        let b_rows: [[f32; 3]; 4] = [
            [-2.5, 0.5, 3.0],
            [6.0, 7.0, 8.0],
            [0.0, 1.0, 2.0],
            [1e-7, 2.0, 2.0],
        ];
        let (a, b) = (
            Tensor::<2>::from_floats(a_rows, &d),
            Tensor::<2>::from_floats(b_rows, &d),
        );
        let joined = Tensor::cat(vec![a.clone(), b.clone()], 1);
        let host = floats(joined.clone().sort(1));
        let values = floats(joined);
        let (merged, order) = by_rank(a.clone(), b.clone(), 1 << 20);
        let (merged, order) = (floats(merged), ints(order));
        assert_eq!(merged, host);
        for max in [2 * 5 * 3, 5 * 3] {
            let (m, o) = by_rank(a.clone(), b.clone(), max);
            assert_eq!(
                (floats(m), ints(o)),
                (merged.clone(), order.clone()),
                "{max}"
            );
        }
        for i in 0..4 {
            let mut seen = [false; 8];
            for j in 0..8 {
                let from = order[i * 8 + j] as usize;
                assert!(!seen[from], "row {i}: column {from} twice");
                seen[from] = true;
                assert_eq!(values[i * 8 + from], merged[i * 8 + j]);
            }
        }
        // Ties keep their columns' order: row 0's 0.5s (a's columns 1, 2, then b's 6) sit at
        // places 2..5, and row 3's 2.0s at 2..8.
        assert_eq!(&order[2..5], &[1, 2, 6]);
        assert_eq!(&order[3 * 8 + 1..3 * 8 + 8], &[0, 1, 2, 3, 4, 6, 7]);
        assert_eq!(floats(merge_rows(a, b)), host);
    }
}
