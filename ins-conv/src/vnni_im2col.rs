//! im2col straight into the BF16 VNNI tiles AMX reads, with AVX-512: for a stride-1 gather
//! (the forward of a stride-1 convolution, and its input gradient) sixteen output pixels of a
//! row read sixteen consecutive input values, so one masked load per kernel tap and pixel block,
//! one conversion of two taps to bf16 and one interleave fill a 64-byte tile row.
//!
//! The plain path ([`crate::im2col::im2col`] then [`crate::bf16::pack_right`]) costs about four
//! times the AMX products it feeds; this is the same result in one pass.

use crate::bf16::{TILE, TILE_K, round_up, to_bf16};
use crate::im2col::ImageSource;

/// A stride-1 gather along both axes: output position `o`, tap `t` read source `o + t + offset`.
#[derive(Clone, Copy, Debug)]
pub struct UnitGather {
    /// The offset along height and width (minus the padding, for a forward pass).
    pub offset: [isize; 2],
}

/// Fills `out` with the VNNI tiles (`[n_pad/16][k_pad/32][16 pairs][16][2]`) of im2col of `src`
/// (`[channels, h, w]`) for output pixels `p0 .. p0 + n` (row width `out_w`), zero-padded.
///
/// # Safety
/// The CPU must have AVX-512 F, BW and BF16 (every CPU with AMX-BF16 does, and the AVX-512
/// BF16 engine needs them too).
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
pub unsafe fn im2col_vnni(
    src: ImageSource,
    kernel: [usize; 2],
    gather: UnitGather,
    out_w: usize,
    p0: usize,
    n: usize,
    n_pad: usize,
    out: &mut Vec<u16>,
) {
    use std::arch::x86_64::*;
    let [h, w] = src.hw;
    let channels = src.channels;
    let [kh, kw] = kernel;
    let k = channels * kh * kw;
    let kp = round_up(k, TILE_K);
    let kblocks = kp / TILE_K;
    assert!(
        src.values.len() >= channels * h * w
            && src.gate.is_none_or(|g| g.len() == src.values.len())
            && n_pad.is_multiple_of(TILE)
            && n <= n_pad
    );
    out.resize(kp * n_pad, 0);
    // Lane j of the result takes bf16 lane j/2 of the first tap for even j, of the second for
    // odd j: the VNNI pair order.
    let interleave = _mm512_set_epi16(
        31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4,
        19, 3, 18, 2, 17, 1, 16, 0,
    );
    // Per tap: the first element of its channel plane, and its row and column offsets.
    let taps: Vec<(usize, isize, isize)> = (0..k)
        .map(|kr| {
            let (c, t) = (kr / (kh * kw), kr % (kh * kw));
            (
                c * h * w,
                (t / kw) as isize + gather.offset[0],
                (t % kw) as isize + gather.offset[1],
            )
        })
        .collect();
    // The offset in the image of tap `kr` for a block starting at output (oy, ox0), and the
    // mask of the lanes that fall inside the image.
    let tap = |kr: usize, oy: usize, ox0: usize| -> (isize, __mmask16) {
        let Some(&(plane, dy, dx)) = taps.get(kr) else {
            return (0, 0);
        };
        let iy = oy as isize + dy;
        if iy < 0 || iy >= h as isize {
            return (0, 0);
        }
        let ix0 = ox0 as isize + dx;
        let mask = if ix0 >= 0 && ix0 + 16 <= w as isize {
            0xFFFF
        } else {
            let lo = (-ix0).clamp(0, 16) as u32;
            let hi = (w as isize - ix0).clamp(0, 16) as u32;
            if hi > lo {
                (((1u32 << hi) - 1) & !((1u32 << lo) - 1)) as u16
            } else {
                0
            }
        };
        ((plane + iy as usize * w) as isize + ix0, mask)
    };
    // Sixteen values from `offset`, the lanes outside `mask` (or with a gate ≤ 0) zero.
    let load = |offset: isize, mask: __mmask16| -> __m512 {
        // SAFETY: masked-off lanes are not read; the others lie inside the image.
        unsafe {
            let v = _mm512_maskz_loadu_ps(mask, src.values.as_ptr().wrapping_offset(offset));
            match src.gate {
                None => v,
                Some(g) => {
                    let g = _mm512_maskz_loadu_ps(mask, g.as_ptr().wrapping_offset(offset));
                    let open = _mm512_mask_cmp_ps_mask(mask, g, _mm512_setzero_ps(), _CMP_GT_OQ);
                    _mm512_maskz_mov_ps(open, v)
                }
            }
        }
    };
    // SAFETY: every tile row written lies inside `out` (resized above); the loads are
    // explained where they happen.
    unsafe {
        let out_ptr = out.as_mut_ptr();
        // Tap pairs outside, pixel blocks inside: the loads walk along image rows.
        let blocks: Vec<(usize, usize, usize, bool)> = (0..n_pad / TILE)
            .map(|nb| {
                let first = nb * TILE;
                let (oy, ox0) = ((p0 + first) / out_w, (p0 + first) % out_w);
                (first, oy, ox0, first + TILE <= n && ox0 + TILE <= out_w)
            })
            .collect();
        for kpair in 0..kp / 2 {
            let (kb, pair) = (2 * kpair / TILE_K, kpair % (TILE_K / 2));
            for (nb, &(first, oy, ox0, whole_row)) in blocks.iter().enumerate() {
                let dst = out_ptr.add(((nb * kblocks + kb) * TILE + pair) * TILE * 2);
                if whole_row {
                    let (o_a, m_a) = tap(2 * kpair, oy, ox0);
                    let (o_b, m_b) = tap(2 * kpair + 1, oy, ox0);
                    let (a, b) = (load(o_a, m_a), load(o_b, m_b));
                    let both: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(b, a));
                    _mm512_storeu_si512(dst as *mut _, _mm512_permutexvar_epi16(interleave, both));
                } else {
                    // A block that crosses a row end or the chunk's end: lane by lane.
                    for j in 0..TILE {
                        for e in 0..2 {
                            let kr = 2 * kpair + e;
                            let p = first + j;
                            let v = if p < n {
                                let (oy, ox) = ((p0 + p) / out_w, (p0 + p) % out_w);
                                let (offset, mask) = tap(kr, oy, ox);
                                if mask & 1 != 0 {
                                    src.at(offset as usize)
                                } else {
                                    0.0
                                }
                            } else {
                                0.0
                            };
                            *dst.add(2 * j + e) = to_bf16(v);
                        }
                    }
                }
            }
        }
    }
}
