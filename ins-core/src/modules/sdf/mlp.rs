//! IDR's SDF MLP: positional encoding, Softplus β = 100, a skip connection.

use burn::nn::Linear;
use burn::prelude::*;

use super::dual::{Dual, encode_dual};
use super::{
    BETA, distance_and_features, distance_features_and_gradient, distance_head, linear_normal,
    zero_inputs,
};
use crate::kernels::dense::dense;
use crate::kernels::softplus::softplus;
use crate::modules::encoding::FourierEncoding;

/// Configuration of an [`SdfMlp`].
#[derive(Config, Debug)]
pub struct SdfMlpConfig {
    /// Octaves of the positional encoding (IDR: 6).
    #[config(default = 6)]
    pub n_freqs: usize,
    /// Width (IDR: 512).
    #[config(default = 512)]
    pub d_hidden: usize,
    /// Hidden layers (IDR: 8).
    #[config(default = 8)]
    pub depth: usize,
    /// Layer that sees the encoded input again (IDR: 4).
    #[config(default = 4)]
    pub skip_at: usize,
    /// Width of the feature vector (IDR: 256).
    #[config(default = 256)]
    pub d_features: usize,
    /// Radius of the initial sphere.
    #[config(default = 0.5)]
    pub radius: f64,
}

/// IDR's SDF MLP.
#[derive(Module, Debug)]
pub struct SdfMlp {
    /// Hidden layers (Softplus β = 100), then the output layer.
    pub layers: Vec<Linear>,
    /// Layer index that sees the encoded input again.
    pub skip_at: usize,
    /// Octaves of the positional encoding.
    pub n_freqs: usize,
    /// Radius of the sphere the field starts as.
    pub radius: f32,
}

impl SdfMlpConfig {
    /// Builds the network (IDR's layer initialisation, distance output near zero): the field
    /// starts as the signed distance to the sphere of radius `radius`.
    pub fn init(&self, device: &Device) -> SdfMlp {
        let d_in = FourierEncoding::new(self.n_freqs).d_out(3);
        let h = self.d_hidden;
        let mut layers = Vec::with_capacity(self.depth + 1);
        for l in 0..=self.depth {
            let input = if l == 0 { d_in } else { h };
            // The layer before the skip narrows so that [h, x] is `h` wide again.
            let output = if l == self.depth {
                1 + self.d_features
            } else if l + 1 == self.skip_at {
                h - d_in
            } else {
                h
            };
            let layer = if l == self.depth {
                distance_head(input, output, device)
            } else {
                let mut lin = linear_normal(
                    input,
                    output,
                    0.0,
                    (2.0f64).sqrt() / (output as f64).sqrt(),
                    0.0,
                    device,
                );
                if l == 0 {
                    // Only the raw coordinates drive the initial field.
                    zero_inputs(&mut lin, 3..d_in);
                } else if l == self.skip_at {
                    // The re-injected encoding (after the hidden part) starts silent too.
                    zero_inputs(&mut lin, (input - d_in + 3)..input);
                }
                lin
            };
            layers.push(layer);
        }
        SdfMlp {
            layers,
            skip_at: self.skip_at,
            n_freqs: self.n_freqs,
            radius: self.radius as f32,
        }
    }
}

impl SdfMlp {
    /// `x [N, 3]` → signed distance `[N]` and features `[N, F]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        let input = FourierEncoding::new(self.n_freqs).encode(x.clone());
        let mut h = input.clone();
        let last = self.layers.len() - 1;
        for (l, layer) in self.layers.iter().enumerate() {
            if l == self.skip_at {
                h = Tensor::cat(vec![h, input.clone()], 1)
                    .mul_scalar(std::f32::consts::FRAC_1_SQRT_2);
            }
            h = dense(layer, h);
            if l < last {
                h = softplus(h, BETA);
            }
        }
        distance_and_features(x, self.radius, h)
    }

    /// Value, features and the exact gradient `∇f [N, 3]` (forward mode), all differentiable
    /// in the parameters and in `x`.
    pub fn forward_with_gradient(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>, Tensor<2>) {
        let input = encode_dual(x.clone(), self.n_freqs);
        let mut d = Dual {
            h: input.h.clone(),
            t: input.t.clone(),
        };
        let last = self.layers.len() - 1;
        for (l, layer) in self.layers.iter().enumerate() {
            if l == self.skip_at {
                let again = Dual {
                    h: input.h.clone(),
                    t: input.t.clone(),
                };
                d = d.cat(again, std::f32::consts::FRAC_1_SQRT_2);
            }
            if l < last {
                d = d.linear(layer).softplus();
            } else {
                d = d.output(layer);
            }
        }
        distance_features_and_gradient(x, self.radius, d, 1.0)
    }
}
