//! AVX-512 BF16 (`VDPBF16PS`) for CPUs that have it but no AMX (AMD Zen 4 and 5, Intel Cooper
//! Lake): the same 32×32 block as [`crate::amx::Tiles::block_32x32`], on the same tile
//! layouts, on vector registers.
//!
//! One `VDPBF16PS` multiplies 16 pairs of bf16 values and adds each pair's two products to one
//! of 16 f32 sums: 32 multiply-adds, twice an f32 FMA's. The right operand's VNNI layout (pairs
//! of consecutive `k` side by side) is exactly what it reads; a pair of the left operand is
//! broadcast to all 16 lanes.

use std::sync::OnceLock;

use crate::bf16::{Block32, TILE, TILE_K};

/// Set (to anything but `0`) to keep every BF16 engine off (this one and AMX), as on a CPU
/// without them.
pub const DISABLE_ENV: &str = "INS_DISABLE_BF16";

/// Whether `name` is set to anything but empty or `0`.
pub(crate) fn env_flag(name: &str) -> bool {
    std::env::var(name).is_ok_and(|v| !v.is_empty() && v != "0")
}

/// Whether the kernel can run here: the CPU has AVX-512 F, BW and BF16, and [`DISABLE_ENV`] is
/// not set. Checked once.
pub fn available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(|| !env_flag(DISABLE_ENV) && cpu_has_avx512_bf16())
}

#[cfg(target_arch = "x86_64")]
fn cpu_has_avx512_bf16() -> bool {
    is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx512bw")
        && is_x86_feature_detected!("avx512bf16")
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_has_avx512_bf16() -> bool {
    false
}

/// Rows of one pass: 8 rows × 2 column tiles of 16 keep 16 sums in registers.
const ROWS: usize = 8;

/// `c` (32×32 f32, `c_stride` floats between rows) = the product block `ops` describes: the
/// same contract as the AMX block.
///
/// # Safety
/// [`available`] must hold, and `c` must be valid for writes of 32 rows of 32 floats,
/// `c_stride` floats apart.
pub unsafe fn block_32x32(ops: &Block32, c: *mut f32, c_stride: usize) {
    ops.check();
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the caller's promises; the slices are long enough (checked above).
    unsafe {
        for (half, (a, init)) in ops.a.iter().zip(ops.init).enumerate() {
            for r0 in (0..TILE).step_by(ROWS) {
                let c = c.add((half * TILE + r0) * c_stride);
                rows_x32(a, ops.b, ops.kblocks, &init[r0 * TILE..], r0, c, c_stride);
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!("AVX-512 BF16 is x86-64 only");
}

/// Rows `r0 .. r0 + 8` of one 16-row tile run `a`, times both column runs `b`, into `c`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn rows_x32(
    a: &[u16],
    b: [&[u16]; 2],
    kblocks: usize,
    init: &[f32],
    r0: usize,
    c: *mut f32,
    c_stride: usize,
) {
    use std::arch::x86_64::*;
    let tile = TILE * TILE_K;
    // SAFETY: every load is inside `a`, `b` (kblocks whole tiles) or `init` (8 rows of 16);
    // the stores are the caller's promise.
    unsafe {
        let mut acc = [[_mm512_setzero_ps(); 2]; ROWS];
        for (r, row) in acc.iter_mut().enumerate() {
            let start = _mm512_loadu_ps(init[r * TILE..].as_ptr());
            *row = [start, start];
        }
        for kb in 0..kblocks {
            let at = a.as_ptr().add(kb * tile + r0 * TILE_K);
            let (b0, b1) = (b[0].as_ptr().add(kb * tile), b[1].as_ptr().add(kb * tile));
            for pair in 0..TILE_K / 2 {
                // 16 columns × 2 consecutive k, as VDPBF16PS pairs them.
                let v0: __m512bh =
                    std::mem::transmute(_mm512_loadu_si512(b0.add(pair * 32) as *const _));
                let v1: __m512bh =
                    std::mem::transmute(_mm512_loadu_si512(b1.add(pair * 32) as *const _));
                for (r, row) in acc.iter_mut().enumerate() {
                    let p = (at.add(r * TILE_K + 2 * pair) as *const i32).read_unaligned();
                    let u: __m512bh = std::mem::transmute(_mm512_set1_epi32(p));
                    row[0] = _mm512_dpbf16_ps(row[0], u, v0);
                    row[1] = _mm512_dpbf16_ps(row[1], u, v1);
                }
            }
        }
        for (r, row) in acc.iter().enumerate() {
            _mm512_storeu_ps(c.add(r * c_stride), row[0]);
            _mm512_storeu_ps(c.add(r * c_stride + TILE), row[1]);
        }
    }
}
