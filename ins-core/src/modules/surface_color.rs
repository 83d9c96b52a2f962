//! IDR's rendering network: the colour of a surface point from its position, normal, the
//! viewing direction and the SDF network's features, `(x, n, v, f) → RGB`.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid};

use super::encoding::FourierEncoding;

/// Configuration of a [`SurfaceColor`].
#[derive(Config, Debug)]
pub struct SurfaceColorConfig {
    /// Width of the SDF features.
    pub d_features: usize,
    /// Hidden width (IDR: 512).
    #[config(default = 512)]
    pub d_hidden: usize,
    /// Hidden layers (IDR: 4).
    #[config(default = 4)]
    pub depth: usize,
    /// Octaves of the view-direction encoding (IDR: 4).
    #[config(default = 4)]
    pub dir_freqs: usize,
}

/// `[x, n, enc(v), f]` → ReLU layers → sigmoid RGB.
#[derive(Module, Debug)]
pub struct SurfaceColor {
    /// Hidden layers, then the RGB layer.
    pub layers: Vec<Linear>,
    /// Octaves of the view-direction encoding.
    pub dir_freqs: usize,
}

impl SurfaceColorConfig {
    /// Builds the network.
    pub fn init(&self, device: &Device) -> SurfaceColor {
        let d_in = 3 + 3 + FourierEncoding::new(self.dir_freqs).d_out(3) + self.d_features;
        let mut layers = Vec::new();
        let mut a = d_in;
        for _ in 0..self.depth {
            layers.push(LinearConfig::new(a, self.d_hidden).init(device));
            a = self.d_hidden;
        }
        layers.push(LinearConfig::new(a, 3).init(device));
        SurfaceColor {
            layers,
            dir_freqs: self.dir_freqs,
        }
    }
}

impl SurfaceColor {
    /// `x, normals, dirs [N, 3]`, `features [N, F]` → RGB `[N, 3]`.
    pub fn forward(&self, x: Tensor<2>, normals: Tensor<2>, dirs: Tensor<2>, features: Tensor<2>) -> Tensor<2> {
        let v = FourierEncoding::new(self.dir_freqs).encode(dirs);
        let mut h = Tensor::cat(vec![x, normals, v, features], 1);
        let last = self.layers.len() - 1;
        for (i, l) in self.layers.iter().enumerate() {
            h = l.forward(h);
            if i < last {
                h = relu(h);
            }
        }
        sigmoid(h)
    }
}
