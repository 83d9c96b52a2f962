//! The paper's content module for 3D: NeRF's MLP (positional encoding with 10 octaves, 8 ReLU
//! layers of 256 with the input re-injected after the 4th, a density head and a 256-d feature).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use super::encoding::FourierEncoding;
use super::mlp::{ReluMlp, ReluMlpConfig};
use crate::kernels::dense::dense;

/// Configuration of a [`MlpGeometry`].
#[derive(Config, Debug)]
pub struct MlpGeometryConfig {
    /// Octaves of the position encoding.
    #[config(default = 10)]
    pub n_freqs: usize,
    /// Width.
    #[config(default = 256)]
    pub d_hidden: usize,
    /// Layers.
    #[config(default = 8)]
    pub depth: usize,
    /// Layer that sees the encoded input again (NeRF: 5, i.e. after the 4th).
    #[config(default = 5)]
    pub skip_at: usize,
}

/// NeRF's MLP: position → (raw density, features).
#[derive(Module, Debug)]
pub struct MlpGeometry {
    /// The trunk.
    pub trunk: ReluMlp,
    /// Density head.
    pub sigma: Linear,
    /// Feature head (input of the colour head).
    pub feature: Linear,
    /// Octaves of the position encoding.
    pub n_freqs: usize,
}

impl MlpGeometryConfig {
    /// Builds the MLP.
    pub fn init(&self, device: &Device) -> MlpGeometry {
        let d_in = FourierEncoding::new(self.n_freqs).d_out(3);
        MlpGeometry {
            trunk: ReluMlpConfig::new(d_in, self.d_hidden, self.depth)
                .with_skip_at(Some(self.skip_at))
                .init(device),
            sigma: LinearConfig::new(self.d_hidden, 1).init(device),
            feature: LinearConfig::new(self.d_hidden, self.d_hidden).init(device),
            n_freqs: self.n_freqs,
        }
    }
}

impl MlpGeometry {
    /// `x [N, 3]` → raw density `[N]` and features `[N, d_hidden]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        let h = self
            .trunk
            .forward(FourierEncoding::new(self.n_freqs).encode(x));
        let [n, _] = h.dims();
        (
            dense(&self.sigma, h.clone()).reshape([n]),
            dense(&self.feature, h),
        )
    }

    /// Width of the features.
    pub fn d_features(&self) -> usize {
        self.feature.weight.dims()[1]
    }
}
