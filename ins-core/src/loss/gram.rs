//! Gram matrices of feature maps.

use burn::backend::DispatchDevice;
use burn::prelude::*;

use super::gram_op::gram_flex;

/// `[B, C, H, W] → [B, C, C]`, `G = F Fᵀ / (C·H·W)`: one op with its own backward on Flex,
/// tensor ops elsewhere.
pub fn gram(features: Tensor<4>) -> Tensor<3> {
    let [b, c, h, w] = features.dims();
    let f = features.reshape([b, c, h * w]);
    let scale = 1.0 / (c * h * w) as f32;
    if matches!(f.device().inner().as_dispatch(), DispatchDevice::Flex(_)) {
        return gram_flex(f, scale);
    }
    f.clone().matmul(f.swap_dims(1, 2)).mul_scalar(scale)
}
