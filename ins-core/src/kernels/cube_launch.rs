//! What the hand-written CubeCL kernels' launches share: their inputs' check, an f32 output on
//! the input's device and the launch sizes for one unit per item (a ray, a point).

use burn::backend::{DType, Shape};
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;
use cubecl::{CubeDim, calculate_cube_count_elemwise};

/// An uninitialised f32 tensor of `shape` on `t`'s device.
pub fn empty_like(t: &CubeTensor, shape: impl Into<Shape>) -> CubeTensor {
    empty_device_dtype(t.client.clone(), t.device.clone(), shape.into(), DType::F32)
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
