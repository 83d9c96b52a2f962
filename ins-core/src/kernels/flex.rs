//! What the hand-written Flex ops share: one strided f32 GEMM (dense layer, Gram matrix),
//! tensors written without zeroing them first, and parallel element-wise fills (sine,
//! softplus).
//!
//! Flex's matmul zero-fills each output as bytes and then copies it to meet an alignment rule
//! (`FlexTensor::empty`), and reads transposed operands through copies. These ops write each
//! result once and read transposes through strides.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use burn::backend::TensorData;
use burn::backend::flex::FlexTensor;
use burn::backend::{DType, DispatchDevice};
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
    // SAFETY: the caller's promise.
    let out = unsafe { written_vec(shape.iter().product(), fill) };
    FlexTensor::from_data(TensorData::new(out, shape))
}

/// [`written`]'s values alone: `len` values that `fill` writes in full (not zeroed first).
///
/// # Safety
/// `fill` must write every one of the `len` elements.
pub(crate) unsafe fn written_vec(len: usize, fill: impl FnOnce(*mut f32)) -> Vec<f32> {
    let mut out = Vec::<f32>::with_capacity(len);
    fill(out.as_mut_ptr());
    // SAFETY: the caller's promise.
    unsafe { out.set_len(len) };
    out
}

/// The f32 values of a contiguous tensor.
pub(crate) fn values(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>().expect("contiguous f32")
}

/// `t` in row-major order (f32). Flex copies a strided matrix element by element with a bounds
/// check each: the density network's feature columns, sliced off its output and copied for the
/// colour network's products, took 4 % of a stylizing step that way. A matrix whose rows are
/// runs of memory is copied here a row at a time, in parallel; anything else goes to Flex.
pub(crate) fn contiguous(t: &FlexTensor) -> FlexTensor {
    let layout = t.layout();
    let strides = layout.strides();
    if t.is_contiguous() || layout.num_dims() != 2 || t.dtype() != DType::F32 {
        return t.to_contiguous();
    }
    let [rows, cols] = layout.shape().dims::<2>();
    if strides[1] != 1 || strides[0] < cols as isize || cols == 0 {
        return t.to_contiguous();
    }
    let (stride, offset) = (strides[0] as usize, layout.start_offset());
    // SAFETY: any bit pattern is an f32; the unaligned prefix is checked empty.
    let (head, all, _) = unsafe { t.bytes().align_to::<f32>() };
    assert!(head.is_empty(), "Flex keeps f32 data aligned");
    let rows_per_job = (CHUNK / cols).max(1);
    let mut out = Vec::with_capacity(rows * cols);
    out.spare_capacity_mut()[..rows * cols]
        .par_chunks_mut(rows_per_job * cols)
        .enumerate()
        .for_each(|(job, dst)| {
            for (k, row) in dst.chunks_mut(cols).enumerate() {
                let start = offset + (job * rows_per_job + k) * stride;
                for (d, s) in row.iter_mut().zip(&all[start..start + cols]) {
                    d.write(*s);
                }
            }
        });
    // SAFETY: every row of every job was written in full.
    unsafe { out.set_len(rows * cols) };
    FlexTensor::from_data(TensorData::new(out, [rows, cols]))
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

/// Whether `x` lives on Flex (with or without autodiff): where the hand-written ops run, and
/// where reading a value back costs nothing.
pub fn on_flex<const D: usize>(x: &Tensor<D>) -> bool {
    is_flex(&x.device())
}

/// Whether `device` is Flex (with or without autodiff); see [`on_flex`].
pub fn is_flex(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Flex(_)
    )
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

#[cfg(test)]
mod tests {
    use super::*;

    fn values_of(t: &FlexTensor) -> Vec<f32> {
        t.clone().into_data().try_to_vec::<f32>().unwrap()
    }

    /// Column and row views (past one parallel job's rows) and a transposed view (Flex's own
    /// copy) come out as Flex lays them out.
    #[test]
    fn a_strided_matrix_is_copied_in_row_major_order() {
        let (rows, cols) = (5000, 10);
        let data: Vec<f32> = (0..rows * cols).map(|i| i as f32 * 0.5 - 7.0).collect();
        let t = FlexTensor::from_data(TensorData::new(data, [rows, cols]));
        let views = [
            t.narrow(1, 2, 7),
            t.narrow(0, 3, 4000).narrow(1, 1, 1),
            t.narrow(1, 0, 9).transpose(0, 1),
            t.clone(),
        ];
        for view in views {
            let copy = contiguous(&view);
            assert!(copy.is_contiguous());
            assert_eq!(copy.layout().shape(), view.layout().shape());
            assert_eq!(values_of(&copy), values_of(&view.to_contiguous()));
        }
    }
}
