//! What the hand-written Flex ops share: one strided f32 GEMM (dense layer, Gram matrix),
//! tensors written without zeroing them first, and parallel element-wise fills (sine,
//! softplus).
//!
//! Flex's matmul zero-fills each output as bytes and then copies it to meet an alignment rule
//! (`FlexTensor::empty`), and reads transposed operands through copies. These ops write each
//! result once and read transposes through strides.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use burn::backend::DispatchDevice;
use burn::backend::TensorData;
use burn::backend::flex::FlexTensor;
use burn::prelude::*;

/// A matrix operand: its first element and its (row, column) strides in elements.
pub(crate) type Strided = (*const f32, [isize; 2]);

/// `dst [m, n]` (row-major) `= scale · a · b`, or `+=` when `accumulate`; `a` is `[m, k]` and
/// `b` is `[k, n]`.
///
/// # Safety
/// Every stride-addressed element must lie inside its buffer, and `dst` must be writable for
/// `m·n` values (and initialised when `accumulate`).
pub(crate) unsafe fn product(
    dims: [usize; 3],
    dst: *mut f32,
    accumulate: bool,
    scale: f32,
    a: Strided,
    b: Strided,
) {
    // SAFETY: the caller's promise.
    unsafe {
        product_on(
            gemm::Parallelism::Rayon(0),
            dims,
            dst,
            accumulate,
            scale,
            a,
            b,
        )
    }
}

/// [`product`] with `parallelism` chosen (`gemm::Parallelism::None` inside a parallel job).
///
/// # Safety
/// As [`product`].
pub(crate) unsafe fn product_on(
    parallelism: gemm::Parallelism,
    [m, k, n]: [usize; 3],
    dst: *mut f32,
    accumulate: bool,
    scale: f32,
    a: Strided,
    b: Strided,
) {
    // SAFETY: the caller's promise.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            n as isize,
            accumulate,
            a.0,
            a.1[1],
            a.1[0],
            b.0,
            b.1[1],
            b.1[0],
            1.0,
            scale,
            false,
            false,
            false,
            parallelism,
        )
    }
}

/// A tensor of `shape` whose values `fill` writes in full (the buffer is not zeroed first).
///
/// # Safety
/// `fill` must write every one of the `shape`'s elements.
pub(crate) unsafe fn written<const D: usize>(
    shape: [usize; D],
    fill: impl FnOnce(*mut f32),
) -> FlexTensor {
    let len = shape.iter().product();
    let mut out = Vec::<f32>::with_capacity(len);
    fill(out.as_mut_ptr());
    // SAFETY: the caller's promise.
    unsafe { out.set_len(len) };
    FlexTensor::from_data(TensorData::new(out, shape))
}

/// The f32 values of a contiguous tensor.
pub(crate) fn values(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>().expect("contiguous f32")
}

/// Elements per parallel job of [`filled`].
const CHUNK: usize = 1 << 14;

/// A vector of `n` values that `fill` writes chunk by chunk (given each chunk's offset), in
/// parallel, never zeroed first. `fill` must write every element of its chunk.
pub(crate) fn filled(n: usize, fill: impl Fn(usize, &mut [MaybeUninit<f32>]) + Sync) -> Vec<f32> {
    let mut out = Vec::with_capacity(n);
    out.spare_capacity_mut()[..n]
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(i, chunk)| fill(i * CHUNK, chunk));
    // SAFETY: `fill` writes every element of every chunk (its contract).
    unsafe { out.set_len(n) };
    out
}

/// Whether `x` lives on Flex (with or without autodiff): where the hand-written ops run.
pub(crate) fn on_flex<const D: usize>(x: &Tensor<D>) -> bool {
    matches!(x.device().inner().as_dispatch(), DispatchDevice::Flex(_))
}

/// The widest vector instructions this CPU offers the element-wise kernels (sine, softplus,
/// Adam).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lanes {
    /// AVX-512F: 16 f32 lanes.
    Avx512,
    /// AVX2 with FMA (most laptops and desktops, AMD before Zen 4): 8 lanes.
    Avx2,
    /// The x86-64 baseline (SSE2, 4 lanes), or another architecture.
    Baseline,
}

impl Lanes {
    /// This CPU's (the standard library caches the detection).
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Self::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return Self::Avx2;
            }
        }
        Self::Baseline
    }
}

/// `fn name(args) = body;` defines `name`, which runs `body` (an `#[inline(always)]` loop) as
/// compiled for the widest vector instructions of [`Lanes::detect`]. A build for the baseline
/// x86-64 CPU runs every loop 4 lanes wide; each copy here is vectorized 16 or 8 wide. The
/// arithmetic is the same in each (Rust never fuses a multiply and an add on its own), so the
/// results are too.
macro_rules! vectorized {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) = $body:path;) => {
        $(#[$m])*
        $vis fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                fn avx512($($arg: $ty),*) {
                    $body($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                fn avx2($($arg: $ty),*) {
                    $body($($arg),*)
                }
                match $crate::kernels::flex::Lanes::detect() {
                    // SAFETY: the CPU has AVX-512F (checked at run time).
                    $crate::kernels::flex::Lanes::Avx512 => return unsafe { avx512($($arg),*) },
                    // SAFETY: the CPU has AVX2 and FMA (checked at run time).
                    $crate::kernels::flex::Lanes::Avx2 => return unsafe { avx2($($arg),*) },
                    $crate::kernels::flex::Lanes::Baseline => {}
                }
            }
            $body($($arg),*)
        }
    };
}
pub(crate) use vectorized;
