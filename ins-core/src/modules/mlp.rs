//! A ReLU MLP with optional re-injection of its input (NeRF's skip connection).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::kernels::dense::dense;
use crate::kernels::dense_chain::dense_chain;

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
        if self.skip_at.is_none() {
            return dense_chain(input, &self.chain());
        }
        let mut h = input.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if i > 0 && Some(i) == self.skip_at {
                h = Tensor::cat(vec![h, input.clone()], 1);
            }
            h = relu(dense(layer, h));
        }
        h
    }

    /// The layers with their ReLUs, for [`dense_chain`] (no skip).
    fn chain(&self) -> Vec<(&Linear, bool)> {
        self.layers.iter().map(|l| (l, true)).collect()
    }
}

/// Hidden ReLU layers, then a linear layer to RGB squashed by a sigmoid: the colour networks
/// of NeRF and IDR.
#[derive(Module, Debug)]
pub struct RgbMlp {
    /// The hidden layers.
    pub hidden: ReluMlp,
    /// The RGB layer.
    pub rgb: Linear,
}

impl RgbMlp {
    /// `depth` hidden layers of width `d_hidden` over `d_input` inputs (none: linear to RGB).
    pub fn new(d_input: usize, d_hidden: usize, depth: usize, device: &Device) -> Self {
        let hidden = ReluMlpConfig::new(d_input, d_hidden, depth).init(device);
        let d_last = if depth == 0 { d_input } else { d_hidden };
        RgbMlp {
            hidden,
            rgb: LinearConfig::new(d_last, 3).init(device),
        }
    }

    /// `[N, d_input] → [N, 3]` in (0, 1).
    pub fn forward(&self, input: Tensor<2>) -> Tensor<2> {
        let logits = if self.hidden.skip_at.is_none() {
            let mut layers = self.hidden.chain();
            layers.push((&self.rgb, false));
            dense_chain(input, &layers)
        } else {
            dense(&self.rgb, self.hidden.forward(input))
        };
        burn::tensor::activation::sigmoid(logits)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_skip_layer_sees_the_input_again() {
        let d = Device::flex();
        d.seed(3);
        let mlp = ReluMlpConfig::new(5, 8, 4).with_skip_at(Some(2)).init(&d);
        let widths: Vec<usize> = mlp.layers.iter().map(|l| l.weight.dims()[0]).collect();
        assert_eq!(widths, [5, 8, 8 + 5, 8]);
        // Zero the path through layers 0 and 1: the output then depends on the input only
        // through the skip, and still does.
        let mut mlp = mlp;
        mlp.layers[1].weight = burn::module::Param::from_tensor(Tensor::zeros([8, 8], &d));
        mlp.layers[1].bias = Some(burn::module::Param::from_tensor(Tensor::zeros([8], &d)));
        let a = mlp.forward(Tensor::<2>::ones([1, 5], &d));
        let b = mlp.forward(Tensor::<2>::ones([1, 5], &d).mul_scalar(-2.0));
        let diff = (a - b).abs().sum().into_scalar::<f32>();
        assert!(
            diff > 1e-4,
            "output ignores the input although the skip carries it"
        );
    }

    #[test]
    fn output_is_the_last_hidden_activation() {
        let d = Device::flex();
        let mlp = ReluMlpConfig::new(3, 16, 2).init(&d);
        let y = mlp.forward(Tensor::<2>::random(
            [64, 3],
            burn::tensor::Distribution::Default,
            &d,
        ));
        assert_eq!(y.dims(), [64, 16]);
        assert!(
            y.min().into_scalar::<f32>() >= 0.0,
            "ReLU output is negative"
        );
    }
}
