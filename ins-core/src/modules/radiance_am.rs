//! The Amalgamation Module of a radiance field (authors' NeRF code): it fuses the content
//! module's raw density σ and features f with style features s,
//!
//! `σ' = λ·σ + (1−λ)·mlp_σ([f, s])`,  `f' = γ·f + (1−γ)·mlp_f([f, s])`,
//!
//! with λ and γ learnable and starting at 1, so the stylized field starts as the pretrained one.

use crate::kernels::dense_chain::dense_chain;
use burn::module::Param;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

/// Configuration of a [`RadianceAm`].
#[derive(Config, Debug)]
pub struct RadianceAmConfig {
    /// Width of the content features.
    pub d_features: usize,
    /// Width of the style features.
    pub d_style: usize,
    /// Hidden width of both branches.
    #[config(default = 64)]
    pub d_hidden: usize,
    /// Linear layers of the feature branch (ReLU between them; the authors use 4).
    #[config(default = 2)]
    pub feature_depth: usize,
}

/// The density branch: `[f, s]` → raw density, blended by λ.
#[derive(Module, Debug)]
pub struct DensityBlend {
    /// Hidden layer.
    pub hidden: Linear,
    /// Output layer.
    pub out: Linear,
    /// λ, `[1]`, starting at 1.
    pub lambda: Param<Tensor<1>>,
}

/// The feature branch: `[f, s]` → features, blended by γ.
#[derive(Module, Debug)]
pub struct FeatureBlend {
    /// The fusion MLP, first to last (linear output).
    pub layers: Vec<Linear>,
    /// γ, `[1]`, starting at 1.
    pub gamma: Param<Tensor<1>>,
}

/// Amalgamation Module for radiance fields.
#[derive(Module, Debug)]
pub struct RadianceAm {
    /// Stylized density.
    pub density: DensityBlend,
    /// Stylized features.
    pub feature: FeatureBlend,
}

impl RadianceAmConfig {
    /// Builds the module with λ = γ = 1.
    pub fn init(&self, device: &Device) -> RadianceAm {
        let d_in = self.d_features + self.d_style;
        RadianceAm {
            density: DensityBlend {
                hidden: LinearConfig::new(d_in, self.d_hidden).init(device),
                out: LinearConfig::new(self.d_hidden, 1).init(device),
                lambda: Param::from_tensor(Tensor::ones([1], device)),
            },
            feature: FeatureBlend {
                layers: (0..self.feature_depth.max(1))
                    .map(|i| {
                        let last = i + 1 == self.feature_depth.max(1);
                        let a = if i == 0 { d_in } else { self.d_hidden };
                        let b = if last { self.d_features } else { self.d_hidden };
                        LinearConfig::new(a, b).init(device)
                    })
                    .collect(),
                gamma: Param::from_tensor(Tensor::ones([1], device)),
            },
        }
    }
}

impl FeatureBlend {
    /// A feature blend alone (surfaces have no density to stylize): `[f, s]` → `depth`
    /// linear layers of width `d_hidden` → `d_features`, with γ = 1.
    pub fn new(
        d_features: usize,
        d_style: usize,
        d_hidden: usize,
        depth: usize,
        device: &Device,
    ) -> Self {
        RadianceAmConfig::new(d_features, d_style)
            .with_d_hidden(d_hidden)
            .with_feature_depth(depth)
            .init(device)
            .feature
    }

    /// `features [N, F]`, `style [N, S]` → `γ·f + (1−γ)·mlp([f, s])`.
    pub fn forward(&self, features: Tensor<2>, style: Tensor<2>) -> Tensor<2> {
        let fs = Tensor::cat(vec![features.clone(), style], 1);
        let last = self.layers.len() - 1;
        let layers: Vec<(&Linear, bool)> = self
            .layers
            .iter()
            .enumerate()
            .map(|(i, l)| (l, i < last))
            .collect();
        let f_s = dense_chain(fs, &layers);
        blend(self.gamma.val(), features, f_s)
    }
}

fn blend<const D: usize>(w: Tensor<1>, a: Tensor<D>, b: Tensor<D>) -> Tensor<D> {
    let w = w.reshape([1; D]);
    a * w.clone() + b * w.neg().add_scalar(1.0)
}

impl RadianceAm {
    /// `sigma [N]`, `features [N, F]`, `style [N, S]` → stylized raw density `[N]` and
    /// features `[N, F]`.
    pub fn forward(
        &self,
        sigma: Tensor<1>,
        features: Tensor<2>,
        style: Tensor<2>,
    ) -> (Tensor<1>, Tensor<2>) {
        let [n, _] = features.dims();
        let fs = Tensor::cat(vec![features.clone(), style.clone()], 1);
        let d = &self.density;
        let sigma_s = dense_chain(fs, &[(&d.hidden, true), (&d.out, false)]).reshape([n]);
        (
            blend(d.lambda.val(), sigma, sigma_s),
            self.feature.forward(features, style),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn starts_as_the_identity_for_any_style() {
        let d = Device::flex();
        d.seed(1);
        let am = RadianceAmConfig::new(15, 8).init(&d);
        let sigma = Tensor::<1>::random([20], Distribution::Default, &d);
        let f = Tensor::<2>::random([20, 15], Distribution::Default, &d);
        for k in 0..2 {
            let s = Tensor::<2>::random([20, 8], Distribution::Normal(k as f64, 1.0), &d);
            let (s2, f2) = am.forward(sigma.clone(), f.clone(), s);
            assert_eq!((s2 - sigma.clone()).abs().max().into_scalar::<f32>(), 0.0);
            assert_eq!((f2 - f.clone()).abs().max().into_scalar::<f32>(), 0.0);
        }
    }
}
