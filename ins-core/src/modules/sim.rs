//! Style Implicit Module: style code → style features.
//!
//! As in the authors' NeRF code the code can be concatenated at every layer and an encoded
//! position can enter at layer 2, so that style features may vary over space.

use crate::kernels::dense::dense;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Configuration of a [`Sim`].
#[derive(Config, Debug)]
pub struct SimConfig {
    /// Length of the style code (number of styles).
    pub d_code: usize,
    /// Hidden and output width.
    #[config(default = 64)]
    pub d_hidden: usize,
    /// Number of linear layers (ReLU between them, the last one linear).
    #[config(default = 2)]
    pub depth: usize,
    /// Concatenate the code again before every layer (authors' NeRF SIM) or only at the first.
    #[config(default = false)]
    pub code_every_layer: bool,
    /// Width of an encoded position entering before layer 2 (0: none).
    #[config(default = 0)]
    pub d_position: usize,
}

/// Style Implicit Module.
#[derive(Module, Debug)]
pub struct Sim {
    /// The layers, first to last.
    pub layers: Vec<Linear>,
    /// See [`SimConfig::code_every_layer`].
    pub code_every_layer: bool,
    /// See [`SimConfig::d_position`].
    pub d_position: usize,
}

impl SimConfig {
    /// Builds the module.
    pub fn init(&self, device: &Device) -> Sim {
        let layers = (0..self.depth.max(1))
            .map(|i| {
                let mut d_in = if i == 0 { self.d_code } else { self.d_hidden };
                if i > 0 && self.code_every_layer {
                    d_in += self.d_code;
                }
                if i == 1 {
                    d_in += self.d_position;
                }
                LinearConfig::new(d_in, self.d_hidden).init(device)
            })
            .collect();
        Sim {
            layers,
            code_every_layer: self.code_every_layer,
            d_position: self.d_position,
        }
    }
}

impl Sim {
    /// How many styles its codes select among.
    pub fn n_styles(&self) -> usize {
        self.layers[0].weight.dims()[0]
    }

    /// Output width.
    pub fn d_out(&self) -> usize {
        self.layers.last().map(|l| l.weight.dims()[1]).unwrap_or(0)
    }

    /// `codes [N, d_code]` (and `position [N, d_position]` when configured) → `[N, d_hidden]`.
    pub fn forward(&self, codes: Tensor<2>, position: Option<Tensor<2>>) -> Tensor<2> {
        let last = self.layers.len() - 1;
        let mut h = codes.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if i > 0 {
                let mut parts = vec![h];
                if self.code_every_layer {
                    parts.push(codes.clone());
                }
                if i == 1
                    && let Some(p) = &position
                {
                    parts.push(p.clone());
                }
                h = if parts.len() == 1 {
                    parts.pop().expect("one part")
                } else {
                    Tensor::cat(parts, 1)
                };
            }
            h = dense(layer, h);
            if i < last {
                h = relu(h);
            }
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn code_at_every_layer_and_position_at_layer_two() {
        let d = Device::flex();
        d.seed(4);
        let sim = SimConfig::new(3)
            .with_d_hidden(16)
            .with_depth(4)
            .with_code_every_layer(true)
            .with_d_position(7)
            .init(&d);
        let inputs: Vec<usize> = sim.layers.iter().map(|l| l.weight.dims()[0]).collect();
        assert_eq!(inputs, [3, 16 + 3 + 7, 16 + 3, 16 + 3]);
        let codes = Tensor::<2>::from_floats([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], &d);
        let pos = Tensor::<2>::random([2, 7], Distribution::Default, &d);
        let y = sim.forward(codes, Some(pos));
        assert_eq!(y.dims(), [2, 16]);
        // Same code, different positions: different style features (they vary over space).
        let rows = y.clone().slice([0..1]) - y.slice([1..2]);
        assert!(rows.abs().sum().into_scalar::<f32>() > 1e-4);
    }

    #[test]
    fn different_codes_give_different_features() {
        let d = Device::flex();
        d.seed(5);
        let sim = SimConfig::new(2).init(&d);
        let y = sim.forward(Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0]], &d), None);
        let rows = y.clone().slice([0..1]) - y.slice([1..2]);
        assert!(rows.abs().sum().into_scalar::<f32>() > 1e-4);
    }
}
