//! The hand-written kernels: every op of INS-rs that has its own backward, and the fused Adam
//! step. Each runs plain Rust (rayon, `gemm`, AVX-512 / AVX2 through [`flex::vectorized`]) on
//! Flex and, where the GPU needs one, a CubeCL kernel on wgpu; each is proven against the same
//! function built from ordinary Burn ops (its tests, `tests/tests/library/hash_grid.rs`,
//! `tests/tests/cpu_fallback.rs`). Why hand-written: Flex's generic ops copy, zero-fill and
//! read transposes through copies, and autodiff keeps every intermediate; these write each
//! result once (measured in docs/measurements.md).
//!
//! - [`flex`]: what the Flex kernels share (a strided GEMM, unzeroed outputs, lanes).
//! - [`dense`]: the linear layer ([`dense_bf16`]: its products in bf16; [`dense_chain`]: an
//!   MLP's layers fused for renders; [`dense_blocks`]: its rows in blocks on the GPU backends,
//!   so its weight gradient fills the GPU; [`fused_mlp`]: a small MLP's layers as one kernel
//!   forward and three backward on the GPU backends); [`sine`]: SIREN's `sin(ω·x)`; [`softplus`]: IDR's
//!   activation and its slope; [`gram`]: Gram matrices.
//! - [`adam`]: Adam's step fused into one pass over each parameter.
//! - [`cube_launch`]: what the CubeCL kernels' launches share.
//! - [`composite`]: volume compositing as one kernel a pass on the GPU backends.
//! - [`samplers`]: the ray samplers (stratified, NeRF's hierarchical draws) as kernels on the
//!   GPU backends; [`jitter`]: their uniform numbers, hashed from a counter.
//! - [`merge_sorted`]: two sorted sets of ray samples merged by one kernel on the GPU backends.
//! - [`section_weights`]: NeuS's section weights as one kernel a pass on the GPU backends.
//! - [`ranked_picks`]: the smoothness term's picks among flagged samples as one kernel on the
//!   GPU backends.
//! - [`hash_grid`]: the multiresolution hash encoding on slices, as CubeCL kernels, and as a
//!   Burn op with both backwards.

pub mod adam;
pub mod composite;
pub mod cube_launch;
pub mod dense;
pub mod dense_bf16;
pub mod dense_blocks;
pub mod dense_chain;
pub mod flex;
pub mod fused_mlp;
pub mod gram;
pub mod hash_grid;
pub mod jitter;
pub mod merge_sorted;
pub mod ranked_picks;
pub mod samplers;
pub mod section_weights;
pub mod sine;
pub mod softplus;

use burn::backend::DispatchDevice;
use burn::prelude::Device;
use burn::tensor::DType;

/// Whether `device` runs CubeCL (wgpu, CUDA), with or without autodiff: where the kernels
/// written as Burn ops for the GPU ([`composite`], [`samplers`], [`merge_sorted`],
/// [`section_weights`]) run.
pub fn cube_device(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        DispatchDevice::Cube(_)
    )
}

/// Whether a GPU kernel takes tensors of these `dtypes` on `device`: a [`cube_device`], all f32
/// (the kernels are written for f32; other precisions keep Burn's ops).
pub fn cube_f32(device: &Device, dtypes: &[DType]) -> bool {
    dtypes.iter().all(|d| *d == DType::F32) && cube_device(device)
}
