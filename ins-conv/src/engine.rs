//! The matrix-product engines of the convolution, which of them this CPU runs, and the BF16
//! 32×32 block each BF16 engine computes.

use crate::amx::{self, Tiles};
use crate::bf16::Block32;
use crate::dpbf16;

/// The matrix-product engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Engine {
    /// f32 products (gemm's AVX-512/AVX2/SSE kernels, picked at run time).
    F32,
    /// BF16 inputs with f32 sums on AMX tiles. Only where [`amx::available`] holds.
    Bf16Amx,
    /// BF16 inputs with f32 sums by AVX-512 BF16 dot products. Only where
    /// [`dpbf16::available`] holds.
    Bf16Avx512,
}

impl Engine {
    /// The fastest BF16 engine this CPU runs (AMX, then AVX-512 BF16), if any.
    pub fn bf16() -> Option<Self> {
        if amx::available() {
            Some(Engine::Bf16Amx)
        } else if dpbf16::available() {
            Some(Engine::Bf16Avx512)
        } else {
            None
        }
    }

    /// [`Engine::bf16`], else `F32`.
    pub fn bf16_or_f32() -> Self {
        Self::bf16().unwrap_or(Engine::F32)
    }

    /// Every engine this CPU runs (for tests and benchmarks).
    pub fn available() -> Vec<Self> {
        let mut engines = vec![Engine::F32];
        if amx::available() {
            engines.push(Engine::Bf16Amx);
        }
        if dpbf16::available() {
            engines.push(Engine::Bf16Avx512);
        }
        engines
    }

    /// Where this engine computes, for messages.
    pub fn describe(self) -> &'static str {
        match self {
            Engine::F32 => "f32",
            Engine::Bf16Amx => "bf16 on AMX",
            Engine::Bf16Avx512 => "bf16 with AVX-512 BF16",
        }
    }
}

/// The BF16 32×32 block of an engine, ready on this thread.
pub(crate) enum Bf16Block {
    Amx(Tiles),
    Avx512,
}

impl Bf16Block {
    pub(crate) fn new(engine: Engine) -> Self {
        match engine {
            Engine::Bf16Amx => Bf16Block::Amx(Tiles::configure()),
            Engine::Bf16Avx512 => {
                assert!(dpbf16::available(), "AVX-512 BF16 is not available");
                Bf16Block::Avx512
            }
            Engine::F32 => unreachable!("f32 has no BF16 block"),
        }
    }

    /// See [`Tiles::block_32x32`].
    ///
    /// # Safety
    /// As there.
    pub(crate) unsafe fn block_32x32(&mut self, ops: &Block32, c: *mut f32, c_stride: usize) {
        // SAFETY: the engine is available (checked in `new`); the rest is the caller's.
        unsafe {
            match self {
                Bf16Block::Amx(tiles) => tiles.block_32x32(ops, c, c_stride),
                Bf16Block::Avx512 => dpbf16::block_32x32(ops, c, c_stride),
            }
        }
    }
}
