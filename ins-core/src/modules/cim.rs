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

    /// The hidden layers' products run in bf16 on flex where the CPU has AVX-512 BF16 (unless
    /// `--precision f32` or `INS_DISABLE_BF16` says otherwise): the README's main job ran about
    /// a fifth faster, its losses within the spread of seeds (docs/measurements.md). The first
    /// layer stays f32: its inner size is 2, nothing to gain, and coordinates rounded to bf16's
    /// 8 bits would land on a coarser grid than the image's pixels.
    fn features(&self, coords: Tensor<2>) -> Tensor<2> {
        self.layers
            .iter()
            .enumerate()
            .fold(coords, |h, (i, layer)| {
                let _precision = crate::kernels::dense_bf16::scope(i > 0);
                layer.forward(h)
            })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::dense_bf16;

    fn host(t: Tensor<2>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// SIREN's features: the hidden layers' products in bf16 and the first layer's in f32,
    /// exactly as layer-by-layer scopes give them; under `forbid`, every layer in f32.
    #[test]
    fn siren_hidden_layers_run_in_bf16_the_first_in_f32() {
        if !dense_bf16::available() {
            eprintln!("no AVX-512 BF16 here: nothing runs in bf16");
            return;
        }
        let d = Device::flex();
        d.seed(3);
        let cim = SirenCimConfig::new()
            .with_d_hidden(64)
            .with_depth(3)
            .init(&d);
        let x = Tensor::<2>::random([70, 2], burn::tensor::Distribution::Uniform(-1.0, 1.0), &d);
        let by_layer = |bf16_from: usize| {
            cim.layers.iter().enumerate().fold(x.clone(), |h, (i, l)| {
                let _p = dense_bf16::scope(i >= bf16_from);
                l.forward(h)
            })
        };
        let mixed = host(cim.features(x.clone()));
        assert_eq!(
            mixed,
            host(by_layer(1)),
            "not bf16 from the second layer on"
        );
        let f32s = {
            let _f32 = dense_bf16::forbid();
            host(cim.features(x.clone()))
        };
        assert_eq!(
            f32s,
            host(by_layer(usize::MAX)),
            "forbid left a layer in bf16"
        );
        let err = mixed
            .iter()
            .zip(&f32s)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err > 0.0 && err < 0.05, "bf16 against f32: {err}");
    }
}
