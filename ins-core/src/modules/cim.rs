//! Content Implicit Modules: coordinates → content features.
//!
//! Any Burn module implementing [`ContentModule`] can be composed into [`crate::modules::ins::Ins`]
//! and trained by the shared trainer: that is the library API for custom INRs.

use burn::prelude::*;

use super::encoding::FourierEncoding;
use super::mlp::{ReluMlp, ReluMlpConfig};
use super::sine::{SineLayer, SineLayerConfig};

/// What INS needs from a content module.
pub trait ContentModule: Module + burn::module::ModuleDisplay {
    /// Width of the feature vector returned by [`ContentModule::features`].
    fn d_features(&self) -> usize;
    /// `[N, d_coords] → [N, d_features]`.
    fn features(&self, coords: Tensor<2>) -> Tensor<2>;
}

/// Configuration of a [`SirenCim`].
#[derive(Config, Debug)]
pub struct SirenCimConfig {
    /// Coordinate dimension (2 for images).
    #[config(default = 2)]
    pub d_coords: usize,
    /// Width of every sine layer.
    #[config(default = 256)]
    pub d_hidden: usize,
    /// Number of sine layers.
    #[config(default = 4)]
    pub depth: usize,
    /// ω₀ of every layer.
    #[config(default = 30.0)]
    pub omega0: f32,
}

/// SIREN content module: `depth` sine layers, SIREN-initialised.
#[derive(Module, Debug)]
pub struct SirenCim {
    /// The sine layers, first to last.
    pub layers: Vec<SineLayer>,
}

impl SirenCimConfig {
    /// Builds the module.
    pub fn init(&self, device: &Device) -> SirenCim {
        let layers = (0..self.depth)
            .map(|i| {
                let d_in = if i == 0 { self.d_coords } else { self.d_hidden };
                SineLayerConfig::new(d_in, self.d_hidden)
                    .with_omega0(self.omega0)
                    .with_is_first(i == 0)
                    .init(device)
            })
            .collect();
        SirenCim { layers }
    }
}

impl ContentModule for SirenCim {
    fn d_features(&self) -> usize {
        self.layers
            .last()
            .map(|l| l.linear.weight.dims()[1])
            .unwrap_or(0)
    }

    fn features(&self, coords: Tensor<2>) -> Tensor<2> {
        self.layers.iter().fold(coords, |h, layer| layer.forward(h))
    }
}

/// Configuration of a [`FourierCim`].
#[derive(Config, Debug)]
pub struct FourierCimConfig {
    /// Coordinate dimension.
    #[config(default = 2)]
    pub d_coords: usize,
    /// Octaves of the positional encoding.
    #[config(default = 10)]
    pub n_freqs: usize,
    /// Hidden width.
    #[config(default = 256)]
    pub d_hidden: usize,
    /// Number of ReLU layers.
    #[config(default = 4)]
    pub depth: usize,
}

/// ReLU MLP over Fourier features (the NeRF-style content module).
#[derive(Module, Debug)]
pub struct FourierCim {
    /// The MLP.
    pub mlp: ReluMlp,
    /// Octaves of the encoding.
    pub n_freqs: usize,
}

impl FourierCimConfig {
    /// Builds the module.
    pub fn init(&self, device: &Device) -> FourierCim {
        let enc = FourierEncoding::new(self.n_freqs);
        FourierCim {
            mlp: ReluMlpConfig::new(enc.d_out(self.d_coords), self.d_hidden, self.depth)
                .init(device),
            n_freqs: self.n_freqs,
        }
    }
}

impl ContentModule for FourierCim {
    fn d_features(&self) -> usize {
        self.mlp
            .layers
            .last()
            .map(|l| l.weight.dims()[1])
            .unwrap_or(0)
    }

    fn features(&self, coords: Tensor<2>) -> Tensor<2> {
        self.mlp
            .forward(FourierEncoding::new(self.n_freqs).encode(coords))
    }
}
