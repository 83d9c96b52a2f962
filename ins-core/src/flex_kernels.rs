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
            gemm::Parallelism::Rayon(0),
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
