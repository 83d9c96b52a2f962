//! What the hand-written CubeCL kernels' launches share: their inputs' check, f32 outputs on
//! the input's device laid out as the kernels write them, and the launch sizes for one unit per
//! item (a ray, a point).

use burn::backend::{DType, Shape};
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_contiguous_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;
use cubecl::{CubeDim, calculate_cube_count_elemwise};

/// An uninitialised f32 tensor of `shape` on `t`'s device, its rows one after another.
///
/// Why not Burn's `empty_device_dtype`: on CUDA it pads each row to a power of two of bytes
/// (at least 16; CubeCL's pitched layout), so a `[N, 5]` tensor has strides `[8, 1]`; the
/// kernels write their outputs row after row (`r·width + k`), and what reads them follows the
/// strides. wgpu lays every tensor out contiguously, which is why lavapipe never showed it.
pub fn empty_like(t: &CubeTensor, shape: impl Into<Shape>) -> CubeTensor {
    let out =
        empty_device_contiguous_dtype(t.client.clone(), t.device.clone(), shape.into(), DType::F32);
    assert!(
        out.is_contiguous(),
        "a kernel's output laid out with strides {:?}",
        out.meta.strides()
    );
    out
}

/// f32 zeros of `shape` on `t`'s device, laid out as [`empty_like`]'s (Burn's zeros are
/// pitched on CUDA too).
pub fn zeros_like(t: &CubeTensor, shape: impl Into<Shape>) -> CubeTensor {
    let out = empty_like(t, shape);
    let len = out.meta.shape().num_elements();
    if len > 0 {
        let (count, dim) = grid(&out, len);
        zero_kernel::launch(&out.client, count, dim, out.clone().into_buffer_arg());
    }
    out
}

#[cube(launch)]
fn zero_kernel(out: &mut [f32]) {
    if ABSOLUTE_POS < out.len() {
        out[ABSOLUTE_POS] = 0.0;
    }
}

/// Launch sizes for one unit per item, `units` items, on `t`'s device.
pub fn grid(t: &CubeTensor, units: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new(&t.client, units);
    (calculate_cube_count_elemwise(&t.client, units, dim), dim)
}

/// Stops, naming `op` and the input, where one of `inputs` is not f32: the kernels are written
/// for f32, and their callers ask [`super::cube_f32`] first.
pub fn assert_f32(op: &str, inputs: &[(&CubeTensor, &str)]) {
    for (x, name) in inputs {
        assert_eq!(x.dtype, DType::F32, "{op} runs in f32 ({name})");
    }
}

/// `tensors` checked f32 ([`assert_f32`], naming `op` and each by `names`) and made contiguous,
/// as the kernels read their inputs.
pub fn contiguous_f32<const K: usize>(
    op: &str,
    tensors: [CubeTensor; K],
    names: [&str; K],
) -> [CubeTensor; K] {
    let named: Vec<_> = tensors.iter().zip(names).collect();
    assert_f32(op, &named);
    tensors.map(into_contiguous)
}
