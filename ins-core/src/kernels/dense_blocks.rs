//! A trained dense layer on the GPU backends, its rows taken in blocks, so that its weight
//! gradient is computed by the whole GPU.
//!
//! Why: the weight gradient `xᵀ·g` of a layer `[N, I] → [N, O]` is a product `[I, N]·[N, O]`
//! with a small output and a long sum (a NeRF step's ~100,000 samples against 64 × 64
//! weights). CubeCL's matmuls (`cubek-matmul` 0.3: every routine Burn's autotune tries) give
//! each cube a tile of the output and walk the whole sum inside it; they do not split the sum
//! across cubes (`k_range = (0, k)`), so a 64 × 64 gradient runs on one to four of an H100's
//! 132 multiprocessors. cuBLAS splits such sums (split-K). Here the forward is the same
//! product written as a batch of `B` blocks of rows against one broadcast weight,
//! `[B, N/B, I]·[1, I, O]`: Burn's autodiff then computes the weight gradient as `B` products
//! `[I, N/B]·[N/B, O]` at once (`B` times the cubes) and sums them over the batch (a small
//! reduction of `B·I·O` values). The bias is added block by block too, so its gradient, a sum
//! over all `N` rows of each of `O` outputs, is taken in two steps: over each block's rows
//! (`B·O` sums at once), then over the blocks. Burn reduces a broadcast bias over all its
//! rows in one reduction, and CubeCL's reductions give each output (four, vectorised) to one
//! unit, plane or cube: `O / 4` of them for a whole layer, 16 for a 64-wide one. Values and
//! gradients are the same sums, grouped differently. Flex keeps its own op (`dense`).

use burn::prelude::*;

use crate::gpu::AdapterKind;
use crate::shape_buckets::compiles_per_size;

/// The output tile a cube computes, for counting cubes (CubeCL's tensor-core stages are 32 to
/// 128 wide; 64 is their middle).
const TILE: usize = 64;
/// Cubes wanted in a weight gradient: about two per multiprocessor of an H100 or H200.
const CUBES: usize = 256;
/// The fewest rows a block sums, so each cube's share stays worth a launch of its tile.
const MIN_ROWS: usize = 256;
/// The most blocks (the batch's partial gradients are `blocks · I · O` values).
const MAX_BLOCKS: usize = 256;

/// How many blocks of rows a trained layer `[n, i] → [n, o]` is split into: the power of two
/// that gives its weight gradient about [`CUBES`] cubes, no more than leaves each block
/// [`MIN_ROWS`] rows, dividing `n` (a bucketed size, `m·2^k`, has large powers of two). One
/// means the plain product.
pub fn row_blocks(n: usize, i: usize, o: usize) -> usize {
    let tiles = i.div_ceil(TILE) * o.div_ceil(TILE);
    let mut blocks = 1;
    while blocks < MAX_BLOCKS
        && blocks * tiles < CUBES
        && n.is_multiple_of(2 * blocks)
        && n / (2 * blocks) >= MIN_ROWS
    {
        blocks *= 2;
    }
    blocks
}

/// Whether long sums off the CPU are taken in blocks (trained layers' rows here, Gram matrices'
/// pixels in `loss::gram`): on a GPU (CUDA, wgpu on a hardware adapter), unless
/// `INS_SPLIT_ROWS=0` (kept to measure one against the other). Not on
/// a software adapter (Mesa's lavapipe): its few CPU threads leave no multiprocessor idle, and
/// there the blocks measured slower (a `nerf-grid` step 3.4 → 5.6 s).
pub fn applies() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let asked = *ON.get_or_init(|| std::env::var("INS_SPLIT_ROWS").as_deref() != Ok("0"));
    asked && crate::gpu::prepared().is_none_or(|r| r.adapter.kind == AdapterKind::Hardware)
}

/// How many blocks a sum of `n` rows into an `i × o` output is taken in on `device`: Some where
/// [`row_blocks`] splits it and blocks apply there (a GPU: not Flex, see [`applies`]), None for
/// the plain product. The one decision for the layers here and the Gram matrices.
pub fn blocks_on(device: &Device, n: usize, i: usize, o: usize) -> Option<usize> {
    let blocks = row_blocks(n, i, o);
    (blocks > 1 && compiles_per_size(device) && applies()).then_some(blocks)
}

/// `x [N, I]·w [I, O]`, for a layer's forward-mode tangents (no bias): see [`trained_affine`].
pub fn trained_product(x: Tensor<2>, w: Tensor<2>) -> Tensor<2> {
    trained_affine(x, w, None)
}

/// `x [N, I]·w [I, O] + b [O]`: by [`row_blocks`] where `w` or `b` is trained on a GPU
/// ([`applies`]), else the plain product and a broadcast bias (Flex, frozen parameters, rows
/// too few or odd to split).
pub fn trained_affine(x: Tensor<2>, w: Tensor<2>, b: Option<Tensor<1>>) -> Tensor<2> {
    let ([n, i], o) = (x.dims(), w.dims()[1]);
    let trained = w.is_tracked() || b.as_ref().is_some_and(|b| b.is_tracked());
    if let Some(blocks) = blocks_on(&x.device(), n, i, o).filter(|_| trained) {
        return affine_in_blocks(x, w, b, blocks);
    }
    let y = x.matmul(w);
    match b {
        Some(b) => y + b.reshape([1, o]),
        None => y,
    }
}

/// `x [N, I]·w [I, O] + b [O]` as `blocks` blocks of `N / blocks` rows against the one
/// broadcast weight (see the module's doc): the plain layer's value, its weight gradient summed
/// block by block. The bias reaches the rows in two steps, `[1, 1, O] → [B, 1, O]` (expanded)
/// `→ [B, N/B, O]` (broadcast), whose backward passes sum in that order reversed: each block's
/// rows first (`B·O` outputs, sums of `N/B`), then the `B` partial sums.
///
/// # Panics
/// Unless `blocks` divides `N`.
pub fn affine_in_blocks(
    x: Tensor<2>,
    w: Tensor<2>,
    b: Option<Tensor<1>>,
    blocks: usize,
) -> Tensor<2> {
    let [n, i] = x.dims();
    let o = w.dims()[1];
    assert!(
        blocks > 0 && n.is_multiple_of(blocks),
        "{blocks} blocks of {n} rows"
    );
    let rows = n / blocks;
    // The bias a block, `[B, 1, O]`, as the result of an op (`+ 0`) on its expanded view: added
    // to the rows, the view itself kept that add out of Burn's fused kernels (a pass over the
    // layer's output more, an unfused add a layer on the CUDA stand-in); `zeros + b` fused
    // neither of its two small kernels. This one fuses.
    let b = b.map(|b| b.reshape([1, 1, o]).expand([blocks, 1, o]).add_scalar(0.0));
    let y = x.reshape([blocks, rows, i]).matmul(w.unsqueeze::<3>());
    match b {
        Some(b) => y + b,
        None => y,
    }
    .reshape([n, o])
}

/// Asserts each of `got` within 1e-5 of the same output of `want` (relative to that output's
/// largest entry): the blocked sums against the plain ones, in tests.
#[cfg(test)]
pub(crate) fn assert_all_close(want: &[Vec<f32>], got: &[Vec<f32>], what: &str) {
    for (k, (want, got)) in want.iter().zip(got).enumerate() {
        let scale = want.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        let err = want
            .iter()
            .zip(got)
            .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(err <= 1e-5 * scale, "output {k}, {what}: {err}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn blocks_divide_the_rows_and_fill_the_gpu_without_thin_blocks() {
        // A grid NeRF's 64-wide layer over a bucketed 131,072 samples: 256 blocks of 512.
        assert_eq!(row_blocks(131_072, 64, 64), 256);
        // The paper's 256-wide layers (16 tiles): 16 blocks make 256 cubes.
        assert_eq!(row_blocks(65_536, 256, 256), 16);
        // Few rows: no block under 256 rows; none at all below 512.
        assert_eq!(row_blocks(2_048, 32, 64), 8);
        assert_eq!(row_blocks(384, 64, 64), 1);
        // An odd count is never split; a count with one factor of two is split once at most.
        assert_eq!(row_blocks(100_001, 64, 64), 1);
        assert_eq!(row_blocks(2 * 50_001, 64, 64), 2);
        // A wide output is split less: its tiles already fill the GPU.
        assert_eq!(row_blocks(1 << 20, 1024, 1024), 1);
        for n in [16usize, 1_000, 4_096, 9_216, 122_880, 1 << 22] {
            let b = row_blocks(n, 64, 16);
            assert!(b.is_power_of_two() && n % b == 0 && (b == 1 || n / b >= MIN_ROWS));
        }
    }

    /// The blocked product has the plain product's value and gradients (input, weight, bias),
    /// on flex under autodiff, for blocks of several sizes.
    #[test]
    fn the_blocked_product_has_the_plain_products_value_and_gradients() {
        let d = Device::flex().autodiff();
        d.seed(5);
        let (n, i, o) = (1_024, 19, 33);
        let x = Tensor::<2>::random([n, i], Distribution::Default, &d);
        let w = Tensor::<2>::random([i, o], Distribution::Default, &d);
        let b = Tensor::<1>::random([o], Distribution::Default, &d);
        let probe = Tensor::<2>::random([n, o], Distribution::Default, &d);
        let run = |blocks: usize| {
            let (x, w, b) = (
                x.clone().require_grad(),
                w.clone().require_grad(),
                b.clone().require_grad(),
            );
            let y = match blocks {
                0 => x.clone().matmul(w.clone()) + b.clone().reshape([1, o]),
                _ => affine_in_blocks(x.clone(), w.clone(), Some(b.clone()), blocks),
            };
            let g = (y.clone() * probe.clone()).sum().backward();
            let flat = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
            [
                flat(y.inner()),
                flat(x.grad(&g).unwrap()),
                flat(w.grad(&g).unwrap()),
                b.grad(&g).unwrap().into_data().try_to_vec::<f32>().unwrap(),
            ]
        };
        let plain = run(0);
        // Value, then the input's, the weight's and the bias's gradients.
        for blocks in [1, 4, 64] {
            assert_all_close(&plain, &run(blocks), &format!("{blocks} blocks"));
        }
    }
}
