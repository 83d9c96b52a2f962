//! The micro-kernel and the bf16 conversions behind [`super`]'s products, in AVX-512 BF16
//! intrinsics.

use std::arch::x86_64::*;

/// Mask of the first `n` of 16 lanes.
#[inline(always)]
fn lanes(n: usize) -> u16 {
    if n >= 16 { 0xffff } else { (1u16 << n) - 1 }
}

/// `c[r][0..n] = start + Σ_p a[r][p]·b[p]` for `R` rows (`rows` of them real) and `B`
/// blocks of 16 columns: row `r`'s pair `p` of `a` at `a[r·a_row + p·a_pair]`, `b` packed
/// ([`super::pack_pairs`], `16·B` wide), `c` f32 rows `c_stride` apart, `start` the `n`
/// values every row's sums begin from (a bias, or zeros).
///
/// # Safety
/// AVX-512 F, BW and BF16; `a` readable at those places, `b` for `pairs · 16·B` pairs, `c`
/// for `rows` rows of `n` values (`n ≤ 16·B`), `start` for `n`.
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn tile<const R: usize, const B: usize>(
    a: *const u32,
    [a_row, a_pair]: [usize; 2],
    rows: usize,
    pairs: usize,
    b: *const u32,
    c: *mut f32,
    c_stride: usize,
    n: usize,
    start: *const f32,
) {
    // SAFETY: the caller's promises bound every load and store.
    unsafe {
        let mut acc = [[_mm512_setzero_ps(); B]; R];
        for row in acc.iter_mut() {
            for (j, v) in row.iter_mut().enumerate() {
                let m = lanes(n.saturating_sub(16 * j));
                *v = _mm512_maskz_loadu_ps(m, start.add(16 * j));
            }
        }
        for p in 0..pairs {
            let mut w = [_mm512_setzero_si512(); B];
            for (j, v) in w.iter_mut().enumerate() {
                *v = _mm512_loadu_si512(b.add((p * B + j) * 16) as *const _);
            }
            for (r, row) in acc.iter_mut().enumerate() {
                // Rows past `rows` repeat the last real one; their sums are not stored.
                let rr = r.min(rows - 1);
                let u = _mm512_set1_epi32(a.add(rr * a_row + p * a_pair).read() as i32);
                for (j, v) in row.iter_mut().enumerate() {
                    *v = _mm512_dpbf16_ps(
                        *v,
                        std::mem::transmute::<__m512i, __m512bh>(u),
                        std::mem::transmute::<__m512i, __m512bh>(w[j]),
                    );
                }
            }
        }
        for (r, row) in acc.iter().enumerate().take(rows) {
            for (j, v) in row.iter().enumerate() {
                let m = lanes(n.saturating_sub(16 * j));
                if m != 0 {
                    _mm512_mask_storeu_ps(c.add(r * c_stride + 16 * j), m, *v);
                }
            }
        }
    }
}

/// `src` as bf16 pairs of consecutive values in `dst` (`src.len().div_ceil(2)` of them; an
/// odd tail paired with 0).
///
/// # Safety
/// AVX-512 F, BW and BF16.
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
pub(super) unsafe fn row_pairs(src: &[f32], dst: &mut [u32]) {
    let k = src.len();
    assert!(dst.len() >= k.div_ceil(2));
    // SAFETY: masked loads stay within `src`, masked stores within `dst` (asserted).
    unsafe {
        let mut i = 0;
        while i < k {
            let lo = _mm512_maskz_loadu_ps(lanes(k - i), src.as_ptr().add(i));
            let hi = _mm512_maskz_loadu_ps(
                lanes(k.saturating_sub(i + 16)),
                src.as_ptr().wrapping_add(i + 16),
            );
            // Lanes past `k` loaded 0, so an odd tail pairs with 0; low half from `lo`.
            let v: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo));
            let pairs = (k - i).min(32).div_ceil(2);
            _mm512_mask_storeu_epi32(dst.as_mut_ptr().add(i / 2) as *mut _, lanes(pairs), v);
            i += 32;
        }
    }
}

/// Row `lo` and row `hi` (or zeros), `n` values each, as `n` bf16 pairs in `dst`.
///
/// # Safety
/// AVX-512 F, BW and BF16.
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
pub(super) unsafe fn interleave(lo: &[f32], hi: Option<&[f32]>, n: usize, dst: &mut [u32]) {
    assert!(lo.len() >= n && hi.is_none_or(|h| h.len() >= n) && dst.len() >= n);
    // Lane 2c takes the low row's c-th value (index c), lane 2c + 1 the high row's (16 + c).
    let mut idx = [0i16; 32];
    for c in 0..16 {
        idx[2 * c] = c as i16;
        idx[2 * c + 1] = 16 + c as i16;
    }
    // SAFETY: masked loads and stores stay within `n` values of each row and of `dst`.
    unsafe {
        let idx = _mm512_loadu_si512(idx.as_ptr() as *const _);
        let mut c = 0;
        while c < n {
            let m = lanes(n - c);
            let l = _mm512_maskz_loadu_ps(m, lo.as_ptr().add(c));
            let h = match hi {
                Some(h) => _mm512_maskz_loadu_ps(m, h.as_ptr().add(c)),
                None => _mm512_setzero_ps(),
            };
            // Low half from `l`, high half from `h`.
            let both: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(h, l));
            let pairs = _mm512_permutexvar_epi16(idx, both);
            _mm512_mask_storeu_epi32(dst.as_mut_ptr().add(c) as *mut _, m, pairs);
            c += 16;
        }
    }
}
