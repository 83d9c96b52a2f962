//! Ray samples sorted along each ray without leaving the device. Burn's CubeCL backends
//! (wgpu, CUDA) have no sort kernel: `sort` reads the tensor back, sorts it on the host and
//! uploads the result, a round trip that drains the GPU's queue twice a step in IDR's volume
//! and once in NeRF's hierarchical sampling. A ray's samples are a short row (tens to a few
//! hundred), so each value's place can be counted instead: the values of its row below it,
//! plus the equal ones before it. That is `K²` comparisons a row, which a GPU does in one fused
//! pass; on Flex, whose sort runs in place on the host, the plain sort stays.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::kernels::flex::on_flex;

/// `x [R, K]` sorted ascending along each row.
pub fn sort_rows(x: Tensor<2>) -> Tensor<2> {
    if on_flex(&x) {
        return x.sort(1);
    }
    let x = x.detach();
    let rank = ranks(&x, MAX_COMPARISONS);
    to_ranks(x, rank)
}

/// `x [R, K]` sorted ascending along each row, with each sorted value's column in `x`
/// (`[R, K]`, for gathering what goes with the values).
pub fn sort_rows_with_indices(x: Tensor<2>) -> (Tensor<2>, Tensor<2, Int>) {
    if on_flex(&x) {
        x.sort_with_indices(1)
    } else {
        by_rank(x.detach(), MAX_COMPARISONS)
    }
}

/// The device path of [`sort_rows_with_indices`]: the values moved to their [`ranks`], and
/// each place's column in `x`.
fn by_rank(x: Tensor<2>, max_comparisons: usize) -> (Tensor<2>, Tensor<2, Int>) {
    let [r, k] = x.dims();
    let rank = ranks(&x, max_comparisons);
    let columns = Tensor::<1, Int>::arange(0..k as i64, &x.device())
        .reshape([1, k])
        .expand([r, k]);
    let order = Tensor::<2, Int>::zeros([r, k], &x.device()).scatter(
        1,
        rank.clone(),
        columns,
        IndexingUpdateOp::Add,
    );
    (to_ranks(x, rank), order)
}

/// The most comparisons [`ranks`] holds at once (16 MB of 32-bit counts): a NeRF render's
/// 8192 rays of 128 samples are ranked in 32 blocks of rows, not in one 0.5 GB buffer, which
/// some adapters could not even allocate.
const MAX_COMPARISONS: usize = 1 << 22;

/// Each value's place in its sorted row `[R, K]`: the values of its row below it, and the
/// equal values in earlier columns (so the places are a permutation), counted a block of rows
/// of at most `max_comparisons` at a time. NaNs have no place; rows must not hold any.
fn ranks(x: &Tensor<2>, max_comparisons: usize) -> Tensor<2, Int> {
    let [r, k] = x.dims();
    let block = (max_comparisons / (k * k).max(1)).max(1);
    if r <= block {
        return block_ranks(x.clone());
    }
    let blocks = (0..r)
        .step_by(block)
        .map(|start| block_ranks(x.clone().slice([start..(start + block).min(r), 0..k])))
        .collect();
    Tensor::cat(blocks, 0)
}

/// [`ranks`] of rows that fit in one block.
fn block_ranks(x: Tensor<2>) -> Tensor<2, Int> {
    let [r, k] = x.dims();
    // [R, K, 1] against [R, 1, K]: entry (k, j) compares value j with value k.
    let this = x.clone().unsqueeze_dim::<3>(2);
    let other = x.unsqueeze_dim::<3>(1);
    let columns = Tensor::<1, Int>::arange(0..k as i64, &this.device());
    let earlier = columns
        .clone()
        .reshape([1, 1, k])
        .lower(columns.reshape([1, k, 1]))
        .int();
    let below = other.clone().lower(this.clone()).int();
    let tied_before = other.equal(this).int() * earlier;
    (below + tied_before).sum_dim(2).reshape([r, k])
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

    /// Rows with ties, negative values, an already sorted and a reversed row: the counted
    /// ranks give Flex's sort exactly, and each index points at its value in the input.
    #[test]
    fn ranks_sort_rows_as_the_host_sort_does() {
        let d = Device::flex();
        let rows: [[f32; 7]; 4] = [
            [0.5, -1.0, 0.5, 3.0, 0.0, 0.5, -2.5],
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0],
            [7.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0],
            [2.0, 2.0, 2.0, 2.0, 1e-7, 2.0, 2.0],
        ];
        let x = Tensor::<2>::from_floats(rows, &d);
        let (sorted, order) = by_rank(x.clone(), MAX_COMPARISONS);
        let (sorted, order) = (floats(sorted), ints(order));
        // Ranked in blocks of three rows and one: the same rows, the same indices.
        let (blocks, block_order) = by_rank(x.clone(), 3 * 7 * 7);
        assert_eq!(floats(blocks), sorted);
        assert_eq!(ints(block_order), order);
        assert_eq!(sorted, floats(x.clone().sort(1)));
        for (i, row) in rows.iter().enumerate() {
            let mut seen = [false; 7];
            for j in 0..7 {
                let from = order[i * 7 + j] as usize;
                assert!(!seen[from], "row {i}: column {from} twice");
                seen[from] = true;
                assert_eq!(row[from], sorted[i * 7 + j]);
            }
        }
        // Ties keep their columns' order: the three 0.5s of row 0 sit at 3, 4, 5.
        assert_eq!(&order[3..6], &[0, 2, 5]);
        assert_eq!(floats(sort_rows(x)), sorted);
    }
}
