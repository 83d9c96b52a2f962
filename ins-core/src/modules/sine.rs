//! SIREN sine layer (Sitzmann et al. 2020): `sin(ω₀ (W x + b))` with SIREN initialisation.

use burn::module::{Initializer, Param};
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::Distribution;

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
    /// The first layer's weights are U(−1/n, 1/n) so that ω₀ spreads the input over several
    /// periods; later layers' U(−√(6/n)/ω₀, √(6/n)/ω₀) keep activations arcsine-distributed.
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
    /// Bound of the uniform weight distribution.
    pub fn weight_bound(&self) -> f64 {
        let n = self.d_input as f64;
        if self.is_first {
            1.0 / n
        } else {
            (6.0 / n).sqrt() / self.omega0 as f64
        }
    }

    /// Bound of the uniform bias distribution: U(−1/√n, 1/√n), the reference implementation's
    /// (PyTorch's default for linear layers, which SIREN keeps for biases).
    pub fn bias_bound(&self) -> f64 {
        1.0 / (self.d_input as f64).sqrt()
    }

    /// Builds the layer with SIREN initialisation.
    pub fn init(&self, device: &Device) -> SineLayer {
        let w = self.weight_bound();
        let mut linear = LinearConfig::new(self.d_input, self.d_output)
            .with_initializer(Initializer::Uniform { min: -w, max: w })
            .init(device);
        let b = self.bias_bound();
        linear.bias = Some(Param::from_tensor(Tensor::random(
            [self.d_output],
            Distribution::Uniform(-b, b),
            device,
        )));
        SineLayer {
            linear,
            omega0: self.omega0,
        }
    }
}

impl SineLayer {
    /// `[N, d_in] → [N, d_out]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        crate::kernels::sine::scaled_sin(crate::kernels::dense::dense(&self.linear, x), self.omega0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn extent(t: Tensor<1>) -> f32 {
        t.abs().max().into_scalar::<f32>()
    }

    #[test]
    fn weights_and_biases_follow_the_siren_reference() {
        let d = Device::flex();
        d.seed(1);
        for (is_first, d_in) in [(true, 2usize), (false, 256)] {
            let cfg = SineLayerConfig::new(d_in, 256).with_is_first(is_first);
            let l = cfg.init(&d);
            let w = extent(l.linear.weight.val().flatten(0, 1));
            let b = extent(l.linear.bias.as_ref().unwrap().val());
            let (wb, bb) = (cfg.weight_bound() as f32, cfg.bias_bound() as f32);
            // Within the bound and filling it (256·d_in draws reach 95 % of it).
            assert!(w <= wb && w > 0.95 * wb, "weights {w} vs bound {wb}");
            assert!(b <= bb && b > 0.9 * bb, "biases {b} vs bound {bb}");
        }
        // Hidden layers: biases are drawn much wider than the weights (1/16 vs ≈ 0.005).
        let cfg = SineLayerConfig::new(256, 256);
        assert!(cfg.bias_bound() > 10.0 * cfg.weight_bound());
    }

    #[test]
    fn hidden_activations_stay_spread_over_depth() {
        // The point of SIREN's initialisation: pre-activations of deep layers stay ≈ N(0, 1)-ish,
        // so sin(·) is neither saturated nor vanishing.
        let d = Device::flex();
        d.seed(2);
        let x = Tensor::<2>::random([4096, 2], Distribution::Uniform(-1.0, 1.0), &d);
        let mut h = SineLayerConfig::new(2, 256)
            .with_is_first(true)
            .init(&d)
            .forward(x);
        for _ in 0..4 {
            h = SineLayerConfig::new(256, 256).init(&d).forward(h);
        }
        let var = h.var(1).mean().into_scalar::<f32>();
        // arcsine distribution on [−1, 1] has variance 1/2.
        assert!((0.3..0.6).contains(&var), "variance {var}");
    }
}
