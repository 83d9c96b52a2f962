//! Gram matrices of feature maps.

use burn::prelude::*;

/// `[B, C, H, W] → [B, C, C]`, `G = F Fᵀ / (C·H·W)`.
pub fn gram(features: Tensor<4>) -> Tensor<3> {
    let [b, c, h, w] = features.dims();
    let f = features.reshape([b, c, h * w]);
    f.clone()
        .matmul(f.swap_dims(1, 2))
        .div_scalar((c * h * w) as f32)
}
