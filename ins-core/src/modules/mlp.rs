//! A ReLU MLP with optional re-injection of its input (NeRF's skip connection).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Configuration of a [`ReluMlp`].
#[derive(Config, Debug)]
pub struct ReluMlpConfig {
    /// Input width.
    pub d_input: usize,
    /// Hidden width.
    pub d_hidden: usize,
    /// Number of hidden (ReLU) layers.
    pub depth: usize,
    /// Before this hidden layer the input is concatenated again (NeRF uses 5, i.e. after the 4th).
    pub skip_at: Option<usize>,
}

/// `depth` ReLU layers; the output is the last hidden activation (width `d_hidden`).
#[derive(Module, Debug)]
pub struct ReluMlp {
    /// The hidden layers.
    pub layers: Vec<Linear>,
    /// Index of the layer that also sees the input.
    pub skip_at: Option<usize>,
}

impl ReluMlpConfig {
    /// Builds the MLP with Burn's default (Kaiming-uniform) initialisation.
    pub fn init(&self, device: &Device) -> ReluMlp {
        let layers = (0..self.depth)
            .map(|i| {
                let d_in = if i == 0 {
                    self.d_input
                } else if Some(i) == self.skip_at {
                    self.d_hidden + self.d_input
                } else {
                    self.d_hidden
                };
                LinearConfig::new(d_in, self.d_hidden).init(device)
            })
            .collect();
        ReluMlp {
            layers,
            skip_at: self.skip_at,
        }
    }
}

impl ReluMlp {
    /// `[N, d_input] → [N, d_hidden]`.
    pub fn forward(&self, input: Tensor<2>) -> Tensor<2> {
        let mut h = input.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if i > 0 && Some(i) == self.skip_at {
                h = Tensor::cat(vec![h, input.clone()], 1);
            }
            h = relu(layer.forward(h));
        }
        h
    }
}
