//! IDR's rendering network: the colour of a surface point from its position, normal, the
//! viewing direction and the SDF network's features, `(x, n, v, f) → RGB`.

use burn::prelude::*;

use super::encoding::FourierEncoding;
use super::mlp::RgbMlp;

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
    /// Hidden ReLU layers and the linear RGB layer.
    pub mlp: RgbMlp,
    /// Octaves of the view-direction encoding.
    pub dir_freqs: usize,
}

impl SurfaceColorConfig {
    /// Builds the network.
    pub fn init(&self, device: &Device) -> SurfaceColor {
        let d_in = 3 + 3 + FourierEncoding::new(self.dir_freqs).d_out(3) + self.d_features;
        SurfaceColor {
            mlp: RgbMlp::new(d_in, self.d_hidden, self.depth, device),
            dir_freqs: self.dir_freqs,
        }
    }
}

impl SurfaceColor {
    /// `x, normals, dirs [N, 3]`, `features [N, F]` → RGB `[N, 3]`.
    pub fn forward(
        &self,
        x: Tensor<2>,
        normals: Tensor<2>,
        dirs: Tensor<2>,
        features: Tensor<2>,
    ) -> Tensor<2> {
        let v = FourierEncoding::new(self.dir_freqs).encode(dirs);
        self.mlp
            .forward(Tensor::cat(vec![x, normals, v, features], 1))
    }
}
