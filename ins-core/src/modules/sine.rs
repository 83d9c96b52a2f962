//! SIREN sine layer (Sitzmann et al. 2020): `sin(ω₀ (W x + b))` with SIREN initialisation.

use burn::module::Initializer;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

/// Configuration of a [`SineLayer`].
#[derive(Config, Debug)]
pub struct SineLayerConfig {
    /// Input width.
    pub d_input: usize,
    /// Output width.
    pub d_output: usize,
    /// Frequency factor ω₀ (30 in the SIREN paper).
    #[config(default = 30.0)]
    pub omega0: f32,
    /// The first layer is initialised U(−1/n, 1/n) so that ω₀ spreads the input over several
    /// periods; later layers U(−√(6/n)/ω₀, √(6/n)/ω₀) keep activations arcsine-distributed.
    #[config(default = false)]
    pub is_first: bool,
}

/// One sine-activated linear layer.
#[derive(Module, Debug)]
pub struct SineLayer {
    /// The affine map inside the sine.
    pub linear: Linear,
    /// ω₀.
    pub omega0: f32,
}

impl SineLayerConfig {
    /// Builds the layer with SIREN initialisation.
    pub fn init(&self, device: &Device) -> SineLayer {
        let n = self.d_input as f64;
        let bound = if self.is_first {
            1.0 / n
        } else {
            (6.0 / n).sqrt() / self.omega0 as f64
        };
        let linear = LinearConfig::new(self.d_input, self.d_output)
            .with_initializer(Initializer::Uniform {
                min: -bound,
                max: bound,
            })
            .init(device);
        SineLayer {
            linear,
            omega0: self.omega0,
        }
    }
}

impl SineLayer {
    /// `[N, d_in] → [N, d_out]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        self.linear.forward(x).mul_scalar(self.omega0).sin()
    }
}
