//! Pixel losses and PSNR.

use burn::prelude::*;

/// Mean squared error.
pub fn mse<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> Tensor<1> {
    (a - b).square().mean()
}

/// PSNR in dB of an MSE on a [0, 1] signal.
pub fn psnr(mse: f64) -> f64 {
    if mse <= 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}
