//! Amalgamation Module: fuses content features with style features.
//!
//! `h = γ·f + (1−γ)·relu(W [f, s] + b)` with a learnable γ that starts at 1, so a freshly
//! built INS reproduces its content module exactly and stylization departs from there
//! (authors' code). With `blend = false` the module is a plain `relu(W [f, s] + b)`.

use burn::module::Param;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::kernels::dense::dense;

/// Configuration of an [`Amalgamation`].
#[derive(Config, Debug)]
pub struct AmalgamationConfig {
    /// Width of the content features (and of the output).
    pub d_features: usize,
    /// Width of the style features.
    pub d_style: usize,
    /// Identity-start blend (true) or plain fusion (false).
    #[config(default = true)]
    pub blend: bool,
}

/// Amalgamation Module.
#[derive(Module, Debug)]
pub struct Amalgamation {
    /// `[f, s] → d_features`.
    pub fuse: Linear,
    /// Blend weight γ (shape `[1]`), starting at 1.
    pub gamma: Param<Tensor<1>>,
    /// Whether γ is used.
    pub blend: bool,
}

impl AmalgamationConfig {
    /// Builds the module with γ = 1.
    pub fn init(&self, device: &Device) -> Amalgamation {
        Amalgamation {
            fuse: LinearConfig::new(self.d_features + self.d_style, self.d_features).init(device),
            gamma: Param::from_tensor(Tensor::ones([1], device)),
            blend: self.blend,
        }
    }
}

impl Amalgamation {
    /// `features [N, F]`, `style [N, S]` → `[N, F]`.
    pub fn forward(&self, features: Tensor<2>, style: Tensor<2>) -> Tensor<2> {
        let mixed = relu(dense(
            &self.fuse,
            Tensor::cat(vec![features.clone(), style], 1),
        ));
        if !self.blend {
            return mixed;
        }
        let gamma = self.gamma.val().unsqueeze::<2>();
        features * gamma.clone() + mixed * (gamma.neg().add_scalar(1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn starts_as_the_identity_whatever_the_style() {
        let d = Device::flex();
        d.seed(6);
        let am = AmalgamationConfig::new(8, 4).init(&d);
        let f = Tensor::<2>::random([10, 8], Distribution::Default, &d);
        for s in 0..3 {
            let style = Tensor::<2>::random([10, 4], Distribution::Normal(s as f64, 1.0), &d);
            let out = am.forward(f.clone(), style);
            let diff = (out - f.clone()).abs().max().into_scalar::<f32>();
            assert_eq!(
                diff, 0.0,
                "AM at initialisation changed the features by {diff}"
            );
        }
    }

    #[test]
    fn gamma_gets_a_gradient_so_stylization_can_leave_the_identity() {
        let d = Device::flex().autodiff();
        d.seed(7);
        let am = AmalgamationConfig::new(8, 4).init(&d);
        let f = Tensor::<2>::random([10, 8], Distribution::Default, &d);
        let style = Tensor::<2>::random([10, 4], Distribution::Default, &d);
        let grads = am.forward(f, style).square().sum().backward();
        let g = am.gamma.val().grad(&grads).expect("γ has a gradient");
        assert!(g.abs().sum().into_scalar::<f32>() > 0.0);
    }
}
