//! Intel AMX: detection, the operating system's permission, and a 32×32 BF16 GEMM block on the
//! tile registers (f32 accumulation), written as inline assembly because Rust's AMX intrinsics
//! are not stable.
//!
//! One `TDPBF16PS` multiplies a 16×32 bf16 tile by a 32×16 one into 16×16 f32 sums: 8192
//! multiply-adds in one instruction, against 16 for an AVX-512 FMA.

use std::sync::OnceLock;

use crate::bf16::{Block32, TILE, TILE_K};

/// Set (to anything but `0`) to keep AMX off even where the CPU has it.
pub const DISABLE_ENV: &str = "INS_DISABLE_AMX";

/// Whether the BF16 AMX kernel can run here: the CPU has AMX-TILE and AMX-BF16, the kernel
/// granted this process the tile state, and neither [`DISABLE_ENV`] nor
/// [`crate::dpbf16::DISABLE_ENV`] is set. Checked once.
pub fn available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(|| {
        let disabled = crate::dpbf16::env_flag(DISABLE_ENV)
            || crate::dpbf16::env_flag(crate::dpbf16::DISABLE_ENV);
        !disabled && cpu_has_amx_bf16() && request_tile_state()
    })
}

#[cfg(target_arch = "x86_64")]
fn cpu_has_amx_bf16() -> bool {
    use std::arch::x86_64::{__cpuid, __cpuid_count};
    #[allow(unused_unsafe)]
    let (max_leaf, leaf7) = unsafe { (__cpuid(0).eax, __cpuid_count(7, 0)) };
    const AMX_BF16: u32 = 1 << 22;
    const AMX_TILE: u32 = 1 << 24;
    max_leaf >= 7 && leaf7.edx & AMX_BF16 != 0 && leaf7.edx & AMX_TILE != 0
}

#[cfg(not(target_arch = "x86_64"))]
fn cpu_has_amx_bf16() -> bool {
    false
}

/// Linux hands out the (8 KB) tile state only on request: `arch_prctl(ARCH_REQ_XCOMP_PERM,
/// XFEATURE_XTILEDATA)`, once per process.
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn request_tile_state() -> bool {
    const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
    const XFEATURE_XTILEDATA: libc::c_long = 18;
    // SAFETY: a plain system call with integer arguments.
    unsafe {
        libc::syscall(
            libc::SYS_arch_prctl,
            ARCH_REQ_XCOMP_PERM,
            XFEATURE_XTILEDATA,
        ) == 0
    }
}

#[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
fn request_tile_state() -> bool {
    false
}

/// The tile configuration: palette 1, all eight tiles 16 rows of 64 bytes.
#[repr(C, align(64))]
struct TileConfig([u8; 64]);

impl TileConfig {
    fn full() -> Self {
        let mut c = [0u8; 64];
        c[0] = 1;
        for t in 0..8 {
            c[16 + 2 * t..18 + 2 * t].copy_from_slice(&64u16.to_le_bytes());
            c[48 + t] = TILE as u8;
        }
        Self(c)
    }
}

/// The tile registers of the calling thread, configured; released on drop.
pub struct Tiles(());

impl Tiles {
    /// Configures this thread's tiles. Only call when [`available`] holds.
    pub fn configure() -> Self {
        assert!(available(), "AMX is not available");
        let cfg = TileConfig::full();
        // SAFETY: AMX is present and permitted (checked above); `cfg` is a valid palette-1
        // configuration, 64-byte aligned.
        unsafe { std::arch::asm!("ldtilecfg [{}]", in(reg) cfg.0.as_ptr(), options(nostack)) };
        Tiles(())
    }

    /// `c` (32×32 f32, `c_stride` floats between rows) = the product block `ops` describes.
    ///
    /// # Safety
    /// `c` must be valid for writes of 32 rows of 32 floats, `c_stride` floats apart.
    pub unsafe fn block_32x32(&mut self, ops: &Block32, c: *mut f32, c_stride: usize) {
        ops.check();
        let Block32 {
            a,
            b,
            kblocks,
            init,
        } = *ops;
        let tile = TILE * TILE_K;
        // SAFETY: the tiles are configured (`self` exists); every load reads 16 rows of 64
        // bytes inside a slice checked above (or `init`); the stores are the caller's promise.
        unsafe {
            std::arch::asm!(
                "tileloadd tmm0, [{i0} + {s}*1]",
                "tileloadd tmm1, [{i0} + {s}*1]",
                "tileloadd tmm2, [{i1} + {s}*1]",
                "tileloadd tmm3, [{i1} + {s}*1]",
                i0 = in(reg) init[0].as_ptr(),
                i1 = in(reg) init[1].as_ptr(),
                s = in(reg) 64usize,
                options(nostack, readonly)
            );
            for kb in 0..kblocks {
                let o = kb * tile;
                std::arch::asm!(
                    "tileloadd tmm4, [{a0} + {s}*1]",
                    "tileloadd tmm5, [{a1} + {s}*1]",
                    "tileloadd tmm6, [{b0} + {s}*1]",
                    "tileloadd tmm7, [{b1} + {s}*1]",
                    "tdpbf16ps tmm0, tmm4, tmm6",
                    "tdpbf16ps tmm1, tmm4, tmm7",
                    "tdpbf16ps tmm2, tmm5, tmm6",
                    "tdpbf16ps tmm3, tmm5, tmm7",
                    a0 = in(reg) a[0].as_ptr().add(o),
                    a1 = in(reg) a[1].as_ptr().add(o),
                    b0 = in(reg) b[0].as_ptr().add(o),
                    b1 = in(reg) b[1].as_ptr().add(o),
                    s = in(reg) 64usize,
                    options(nostack, readonly)
                );
            }
            std::arch::asm!(
                "tilestored [{c00} + {s}*1], tmm0",
                "tilestored [{c01} + {s}*1], tmm1",
                "tilestored [{c10} + {s}*1], tmm2",
                "tilestored [{c11} + {s}*1], tmm3",
                c00 = in(reg) c,
                c01 = in(reg) c.add(16),
                c10 = in(reg) c.add(16 * c_stride),
                c11 = in(reg) c.add(16 * c_stride + 16),
                s = in(reg) 4 * c_stride,
                options(nostack)
            );
        }
    }
}

impl Drop for Tiles {
    fn drop(&mut self) {
        // SAFETY: releases the state configured in `configure`.
        unsafe { std::arch::asm!("tilerelease", options(nostack, nomem)) };
    }
}
