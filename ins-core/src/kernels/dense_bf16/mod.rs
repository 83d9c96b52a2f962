//! The dense layer's three products in bf16 with AVX-512 BF16 (`VDPBF16PS`): operands rounded
//! to bf16, products summed in f32.
//!
//! Why: a NeRF's small MLPs (widths 16–64) run the `gemm` crate's f32 kernels at about 87 % of
//! what the FMA units can do (196 GFLOP/s on 2 Zen 4 cores for `[393216, 64]·[64, 64]`), and
//! those products were 40 % of a stylization step. One `VDPBF16PS` does 32 multiply-adds where
//! an FMA does 16. Mixed precision as GPUs train these fields (tiny-cuda-nn's MLPs run in
//! fp16): bf16 keeps f32's range, so nothing overflows; weights, sums and everything outside
//! the products stay f32.
//!
//! One micro-kernel serves all three products: rows of the left operand as bf16 pairs
//! (consecutive `k`), the right operand packed as VDPBF16PS reads it (for each pair of `k`,
//! 16 columns × 2), f32 sums starting from the bias (or zero) and written once. Outputs wider
//! than the micro-kernel's 64 columns run panel by panel, so the paper's 256-wide NeRF MLP
//! gains as the small ones do (`bench nerf-pretrain` on flex about 30 % faster, 2 Zen 4 cores).

use rayon::prelude::*;

/// Whether the CPU can run these kernels (AVX-512 F, BW and BF16) and `INS_DISABLE_BF16` is
/// not set: the convolutions' own check (made once there), the same switch for both.
pub use ins_conv::dpbf16::available;

/// Rows `0..k` of a row-major f32 matrix (`stride` floats apart, `n` columns) as bf16 pairs of
/// consecutive rows: `out[p·width + c]` holds rows `2p` and `2p + 1` of column `c` (low, high
/// half), as VDPBF16PS pairs them; missing rows and columns `n..width` are 0. This is the right
/// operand's layout (16 columns a vector) and, read along `p`, a transposed left operand's.
pub(super) fn pack_pairs(src: &[f32], [k, n]: [usize; 2], stride: usize, width: usize) -> Vec<u32> {
    let pairs = k.div_ceil(2);
    let mut out = vec![0u32; pairs * width];
    for p in 0..pairs {
        let lo = &src[2 * p * stride..];
        let hi = (2 * p + 1 < k).then(|| &src[(2 * p + 1) * stride..]);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX-512 BF16 (every caller checked `available`); the rows hold `n` values
        // (asserted inside).
        unsafe {
            x86::interleave(lo, hi, n, &mut out[p * width..(p + 1) * width])
        };
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (lo, hi, n);
    }
    out
}

/// Rows in one call of the micro-kernel for `blocks` column blocks of 16: as many as keep the
/// sums within 24 of the 32 vector registers.
const fn rows_for(blocks: usize) -> usize {
    match blocks {
        1 => 12,
        2 => 12,
        3 => 8,
        _ => 6,
    }
}

pub mod columns;
#[cfg(target_arch = "x86_64")]
mod x86;

/// Columns of one panel of a packed right operand: the micro-kernel's widest tile (4 vectors).
const PANEL: usize = 64;

/// The right operand `[k, n]` (row-major, rows `stride` apart) packed for [`product_packed`]:
/// panels of [`PANEL`] columns (the last one narrower) one after another, each laid out by
/// [`pack_pairs`] (`16·⌈cols/16⌉` wide). Up to 64 columns it is one panel, `pack_pairs`'s.
pub(super) fn pack_panels(src: &[f32], [k, n]: [usize; 2], stride: usize) -> Vec<u32> {
    let mut out = Vec::with_capacity(k.div_ceil(2) * n.div_ceil(16) * 16);
    for c0 in (0..n).step_by(PANEL) {
        let cols = PANEL.min(n - c0);
        out.extend(pack_pairs(
            &src[c0..],
            [k, cols],
            stride,
            cols.div_ceil(16) * 16,
        ));
    }
    out
}

/// `c [m, n] = start + a·b` serially (`start`: the `n` values every row begins from): row `r`'s
/// pair `p` of `a` at `a[r·a_row + p·a_pair]`, `b` packed by [`pack_panels`], `c` row-major,
/// every value written. Panel by panel, so a panel's packed columns stay in cache while every
/// row tile reads them.
///
/// # Safety
/// `c` valid for `m·n` writes.
pub(super) unsafe fn product_packed(
    a: &[u32],
    a_strides: [usize; 2],
    [m, pairs, n]: [usize; 3],
    b: &[u32],
    start: &[f32],
    c: *mut f32,
) {
    assert!(available() && m > 0 && pairs > 0 && n > 0);
    assert!(b.len() >= pairs * n.div_ceil(16) * 16 && start.len() >= n);
    let last = (m - 1) * a_strides[0] + (pairs - 1) * a_strides[1];
    assert!(a.len() > last, "left operand too short");
    for c0 in (0..n).step_by(PANEL) {
        let cols = PANEL.min(n - c0);
        // Every panel before this one is PANEL columns wide.
        let panel = b[pairs * c0..].as_ptr();
        let start = start[c0..].as_ptr();
        #[cfg(target_arch = "x86_64")]
        macro_rules! run {
            ($b:literal) => {{
                const R: usize = rows_for($b);
                for t in (0..m).step_by(R) {
                    // SAFETY: AVX-512 BF16 (available); rows t.. of `a` within `last`, the
                    // panel and `start` long enough (checked above), `c` the caller's promise.
                    unsafe {
                        x86::tile::<R, $b>(
                            a.as_ptr().add(t * a_strides[0]),
                            a_strides,
                            R.min(m - t),
                            pairs,
                            panel,
                            c.add(t * n + c0),
                            n,
                            cols,
                            start,
                        )
                    }
                }
            }};
        }
        #[cfg(target_arch = "x86_64")]
        match cols.div_ceil(16) {
            1 => run!(1),
            2 => run!(2),
            3 => run!(3),
            _ => run!(4),
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (panel, start, cols);
    }
}

/// Rows of one parallel job of the row-wise products.
pub(super) const ROW_CHUNK: usize = 256;

/// `start + a [m, k] · b` → `[m, n]` (row-major `a`, `b` packed for `[k, n]`), rows in
/// parallel, the result written once (never zeroed first).
fn rows_times(a: &[f32], [m, k, n]: [usize; 3], b: &[u32], start: &[f32]) -> Vec<f32> {
    let pairs = k.div_ceil(2);
    let mut out = Vec::<f32>::with_capacity(m * n);
    out.spare_capacity_mut()[..m * n]
        .par_chunks_mut(ROW_CHUNK * n)
        .enumerate()
        .for_each(|(ci, out)| {
            let rows = out.len() / n;
            let src = &a[ci * ROW_CHUNK * k..][..rows * k];
            let mut ap = vec![0u32; rows * pairs];
            for (r, dst) in ap.chunks_exact_mut(pairs).enumerate() {
                row_as_pairs(&src[r * k..(r + 1) * k], dst);
            }
            // SAFETY: `out` holds `rows·n` values.
            unsafe {
                product_packed(
                    &ap,
                    [pairs, 1],
                    [rows, pairs, n],
                    b,
                    start,
                    out.as_mut_ptr() as *mut f32,
                )
            };
        });
    // SAFETY: every chunk's rows were written in full.
    unsafe { out.set_len(m * n) };
    out
}

/// A row of f32 values as bf16 pairs of consecutive values (an odd tail paired with 0).
pub(super) fn row_as_pairs(src: &[f32], dst: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: AVX-512 BF16 (the callers checked `available`).
    unsafe {
        x86::row_pairs(src, dst)
    }
}

/// `x [n, i] · w [i, o] + bias [o]` (row-major), the operands rounded to bf16.
///
/// # Panics
/// Unless [`available`], `o > 0` and `i > 0`.
pub fn forward(x: &[f32], w: &[f32], bias: &[f32], [n, i, o]: [usize; 3]) -> Vec<f32> {
    assert!(available() && o > 0 && i > 0);
    assert!(x.len() == n * i && w.len() == i * o && bias.len() == o);
    let b = pack_panels(w, [i, o], o);
    rows_times(x, [n, i, o], &b, bias)
}

/// `g [n, o] · wᵀ` → `[n, i]` for `w [i, o]` (row-major), the operands rounded to bf16.
///
/// # Panics
/// Unless [`available`], `i > 0` and `o > 0`.
pub fn grad_input(g: &[f32], w: &[f32], [n, o, i]: [usize; 3]) -> Vec<f32> {
    assert!(available() && i > 0 && o > 0);
    assert!(g.len() == n * o && w.len() == i * o);
    let wt: Vec<f32> = (0..o * i).map(|t| w[(t % i) * o + t / i]).collect();
    let b = pack_panels(&wt, [o, i], i);
    rows_times(g, [n, o, i], &b, &vec![0.0; i])
}

/// Rows of one job of [`grad_weight`]'s sum, at least: a job's `[i, o]` sum is added to the
/// others' at the end, so wide layers take more rows a job (`i·o / 32`) to keep that addition a
/// small part of the product (a 256 × 256 layer: 2048 rows).
const SUM_CHUNK: usize = 512;

/// `xᵀ [i, n] · g [n, o]` → `[i, o]`, the operands rounded to bf16: the sum over rows runs in
/// chunks on both cores, the chunks' f32 sums added in their order.
///
/// # Panics
/// Unless [`available`], `o > 0` and `i > 0`.
pub fn grad_weight(x: &[f32], g: &[f32], [n, i, o]: [usize; 3]) -> Vec<f32> {
    assert!(available() && o > 0 && i > 0);
    assert!(x.len() == n * i && g.len() == n * o);
    let i_wide = i.div_ceil(16) * 16;
    let chunk = SUM_CHUNK.max(i * o / 32);
    let zero = vec![0.0f32; o];
    let partials: Vec<Vec<f32>> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|ci| {
            let (r0, rows) = (ci * chunk, chunk.min(n - ci * chunk));
            // Pairs of rows of x and of g: xᵀ's row c (x's column c) is read down `p`.
            let xp = pack_pairs(&x[r0 * i..(r0 + rows) * i], [rows, i], i, i_wide);
            let gp = pack_panels(&g[r0 * o..(r0 + rows) * o], [rows, o], o);
            let mut part = vec![0.0f32; i * o];
            // SAFETY: `part` holds `i·o` values.
            unsafe {
                product_packed(
                    &xp,
                    [1, i_wide],
                    [i, rows.div_ceil(2), o],
                    &gp,
                    &zero,
                    part.as_mut_ptr(),
                )
            };
            part
        })
        .collect();
    let mut out = vec![0.0f32; i * o];
    for p in &partials {
        out.iter_mut().zip(p).for_each(|(d, s)| *d += s);
    }
    out
}

/// What this thread's dense products run in.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Setting {
    F32,
    Bf16,
    /// f32, whatever a scope inside asks ([`forbid`]).
    F32Only,
}

thread_local! {
    static SETTING: std::cell::Cell<Setting> = const { std::cell::Cell::new(Setting::F32) };
}

/// Dense products on this thread in bf16 (`on`, where [`available`]) or f32 until the returned
/// guard drops (then as before), unless a [`forbid`] holds. A model whose products suit bf16
/// enters it around its own evaluation; the backward of each product runs in the precision
/// its forward ran in.
#[must_use = "the setting lasts as long as the guard"]
pub fn scope(on: bool) -> Scope {
    let set = |s: Setting| match s {
        Setting::F32Only => s,
        _ if on && available() => Setting::Bf16,
        _ => Setting::F32,
    };
    Scope(SETTING.with(|c| c.replace(set(c.get()))))
}

/// Dense products on this thread in f32 until the guard drops, whatever scopes inside ask:
/// for comparisons with f32 backends, and `--precision f32`.
#[must_use = "the setting lasts as long as the guard"]
pub fn forbid() -> Scope {
    Scope(SETTING.replace(Setting::F32Only))
}

/// Whether a [`scope`] asking for bf16 would get it on this thread: the CPU can, and no
/// [`forbid`] holds (`--precision f32`). For products outside a model's scope that follow the
/// run's precision (NNFM's matches).
pub fn allowed() -> bool {
    SETTING.get() != Setting::F32Only && available()
}

/// Whether this thread's dense products run in bf16 now.
pub fn active() -> bool {
    SETTING.get() == Setting::Bf16
}

/// Restores the previous setting when dropped.
pub struct Scope(Setting);

impl Drop for Scope {
    fn drop(&mut self) {
        SETTING.set(self.0);
    }
}

/// Whether a product whose output rows are `columns` wide runs faster in bf16: from 32
/// columns up (narrower outputs read as much for fewer products, and the `gemm` crate's f32
/// kernels were as fast or faster: 4.0 against 5.6 ms for 16 columns).
pub fn worth_it(columns: usize) -> bool {
    columns >= 32
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;
    use burn::prelude::*;
    use ins_conv::bf16::{from_bf16, to_bf16};

    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
            })
            .collect()
    }

    fn rounded(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&x| from_bf16(to_bf16(x)) as f64).collect()
    }

    /// `a [m, k] · b [k, n]` in f64, and the sums of the terms' magnitudes (what bounds f32's
    /// rounding of the sum).
    fn reference(a: &[f64], b: &[f64], [m, k, n]: [usize; 3]) -> (Vec<f64>, Vec<f64>) {
        let (mut out, mut mag) = (vec![0.0; m * n], vec![0.0; m * n]);
        for r in 0..m {
            for t in 0..k {
                for c in 0..n {
                    out[r * n + c] += a[r * k + t] * b[t * n + c];
                    mag[r * n + c] += (a[r * k + t] * b[t * n + c]).abs();
                }
            }
        }
        (out, mag)
    }

    fn transpose(a: &[f32], rows: usize, cols: usize) -> Vec<f32> {
        (0..rows * cols)
            .map(|t| a[(t % rows) * cols + t / rows])
            .collect()
    }

    /// Within f32's summation error of the exact sum of the rounded operands' products.
    fn assert_exact(got: &[f32], (want, mag): (Vec<f64>, Vec<f64>), what: &str) {
        assert_eq!(got.len(), want.len(), "{what}");
        for (j, ((&g, w), m)) in got.iter().zip(&want).zip(&mag).enumerate() {
            let err = (g as f64 - w).abs();
            assert!(
                err <= 1e-6 * (m + 1e-3),
                "{what}[{j}]: {g} against {w} (terms {m})"
            );
        }
    }

    /// The three products are sums of the bf16-rounded operands' products, summed in f32: for
    /// odd inner sizes (a pair with one value), outputs that are not whole vectors, rows past
    /// a tile, a parallel job and a chunk of the weight gradient's sum, and outputs wider than
    /// a panel (a whole and a partial panel; three jobs of a wide layer's larger chunk). Where
    /// the CPU lacks AVX-512 BF16, what must hold is that nothing turns them on.
    #[test]
    fn products_are_exact_sums_of_rounded_operands() {
        #[cfg(target_arch = "x86_64")]
        let cpu = is_x86_feature_detected!("avx512bf16") && is_x86_feature_detected!("avx512bw");
        #[cfg(not(target_arch = "x86_64"))]
        let cpu = false;
        let disabled = std::env::var("INS_DISABLE_BF16").is_ok_and(|v| !v.is_empty() && v != "0");
        assert_eq!(available(), cpu && !disabled);
        {
            let _on = scope(true);
            assert_eq!(active(), available());
        }
        assert!(!active(), "the scope outlived its guard");
        {
            let _f32 = forbid();
            let _on = scope(true);
            assert!(!active(), "a scope inside a forbid turned bf16 on");
        }
        if !available() {
            eprintln!("no AVX-512 BF16 here: only the fallback choice was checked");
            return;
        }
        for (s, [n, i, o]) in [
            [517, 27, 3],
            [517, 64, 16],
            [300, 33, 64],
            [5, 64, 33],
            [1, 1, 1],
            [1200, 136, 136],
            [37, 283, 130],
        ]
        .into_iter()
        .enumerate()
        {
            let what = format!("{n}×{i}→{o}");
            let s = s as u64 * 10;
            let (x, w, b, g) = (
                values(n * i, s + 1),
                values(i * o, s + 2),
                values(o, s + 3),
                values(n * o, s + 4),
            );
            let mut want = reference(&rounded(&x), &rounded(&w), [n, i, o]);
            for (r, v) in want.0.iter_mut().enumerate() {
                *v += b[r % o] as f64;
            }
            assert_exact(&forward(&x, &w, &b, [n, i, o]), want, &format!("y {what}"));
            let wt = transpose(&w, i, o);
            let want = reference(&rounded(&g), &rounded(&wt), [n, o, i]);
            assert_exact(&grad_input(&g, &w, [n, o, i]), want, &format!("dx {what}"));
            let xt = transpose(&x, n, i);
            let want = reference(&rounded(&xt), &rounded(&g), [i, n, o]);
            assert_exact(&grad_weight(&x, &g, [n, i, o]), want, &format!("dw {what}"));
        }
    }

    /// Through the dense layer on Flex: inside a scope its value and gradients are the bf16
    /// products (near f32's, not equal), and a backward run after the scope ended still
    /// runs in the precision its forward ran in; outside, f32 as before.
    #[test]
    fn dense_layer_runs_in_the_precision_of_its_scope() {
        if !available() {
            eprintln!("no AVX-512 BF16 here: nothing runs in bf16");
            return;
        }
        let d = Device::flex().autodiff();
        d.seed(5);
        let (n, i, o) = (300, 48, 64);
        let layer = LinearConfig::new(i, o).init(&d);
        let x = Tensor::<2>::random([n, i], burn::tensor::Distribution::Default, &d).require_grad();
        let probe = Tensor::<2>::random([n, o], burn::tensor::Distribution::Default, &d);
        let y32 = crate::kernels::dense::dense(&layer, x.clone());
        let y16 = {
            let _on = scope(true);
            crate::kernels::dense::dense(&layer, x.clone())
        };
        let host = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
        let (w, xs, ps) = (
            host(layer.weight.val()),
            host(x.clone()),
            host(probe.clone()),
        );
        let bias = host(layer.bias.as_ref().unwrap().val().reshape([1, o]));
        assert_eq!(host(y16.clone()), forward(&xs, &w, &bias, [n, i, o]));
        let (a, b) = (host(y32.clone()), host(y16.clone()));
        let err = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f32::max);
        assert!(err > 0.0 && err < 2e-2, "bf16 against f32: {err}");
        let grads = (y16 * probe).sum().backward();
        let dw = host(layer.weight.val().grad(&grads).unwrap());
        let dx = host(x.grad(&grads).unwrap());
        assert_eq!(
            dw,
            grad_weight(&xs, &ps, [n, i, o]),
            "dw not the bf16 product"
        );
        assert_eq!(
            dx,
            grad_input(&ps, &w, [n, o, i]),
            "dx not the bf16 product"
        );
    }
}
