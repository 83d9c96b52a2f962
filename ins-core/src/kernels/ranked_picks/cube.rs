//! The picks as a CubeCL kernel, one unit a pick: its rank among the flagged entries, in
//! integers exactly as `render::flagged_picks` computes it, then the entry of that rank.

use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use crate::kernels::cube_launch::{assert_f32, empty_like, grid};

/// Pick `i`'s entry (`out[i]`) and weight (`out[k + i]`): with `T = counts[N − 1]` flagged and
/// `T ≥ k`, rank `⌊(i·T + o)/k⌋` with `o = ⌊uᵢ·T/steps⌋` (`uᵢ = offsets[i]`, below `steps`),
/// each product split so that none outgrows 32 bits; with `T < k`, rank `i`. The entry of rank
/// `ρ` is the first whose running count passes `ρ`; a rank past the flagged ones (a filler)
/// gives entry 0, weight 0.
#[cube(launch)]
fn pick_kernel(counts: &[f32], offsets: &[f32], out: &mut [f32], #[comptime] steps: u32) {
    let k = offsets.len();
    if ABSOLUTE_POS >= k {
        terminate!();
    }
    let n = counts.len();
    let i = u32::cast_from(ABSOLUTE_POS);
    let picks = u32::cast_from(k);
    let total = u32::cast_from(counts[n - 1]);
    let mut rank = i;
    if total >= picks {
        let u = u32::cast_from(offsets[ABSOLUTE_POS]);
        let offset = u * (total / steps) + (u * (total % steps)) / steps;
        rank = i * (total / picks) + (i * (total % picks) + offset) / picks;
    }
    let mut entry = 0u32;
    let mut weight = 0.0f32;
    if rank < total {
        // The first j with counts[j] > rank: counts is non-decreasing and ends at T > rank.
        let mut lo = 0u32;
        let mut hi = u32::cast_from(n) - 1;
        loop {
            if lo >= hi {
                break;
            }
            let mid = (lo + hi) / 2;
            if u32::cast_from(counts[mid as usize]) > rank {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        entry = lo;
        weight = 1.0;
    }
    out[ABSOLUTE_POS] = f32::cast_from(entry);
    out[k + ABSOLUTE_POS] = weight;
}

/// `[2, k]`: each pick's entry (as f32, exact below 2²⁴) and weight, from the running count of
/// flags `counts [N]` (`N ≥ 1`) and the picks' offsets in their strata `offsets [k]` (integers
/// below `steps`).
pub fn pick(counts: CubeTensor, offsets: CubeTensor, steps: u32) -> CubeTensor {
    assert_f32(
        "picking flagged entries",
        &[(&counts, "running count"), (&offsets, "offsets")],
    );
    let k = offsets.meta.shape()[0];
    let out = empty_like(&counts, [2, k]);
    if k == 0 {
        return out;
    }
    let (count, dim) = grid(&counts, k);
    pick_kernel::launch(
        &counts.client.clone(),
        count,
        dim,
        into_contiguous(counts).into_buffer_arg(),
        into_contiguous(offsets).into_buffer_arg(),
        out.clone().into_buffer_arg(),
        steps,
    );
    out
}
