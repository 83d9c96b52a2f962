//! Amalgamation Module: fuses content features with style features.
//!
//! `h = γ·f + (1−γ)·relu(W [f, s] + b)` with a learnable γ that starts at 1, so a freshly
//! built INS reproduces its content module exactly and stylization departs from there
//! (authors' code). With `blend = false` the module is a plain `relu(W [f, s] + b)`.

use burn::module::Param;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::kernels::dense::dense_with;

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
    /// `features [P, F]`, one style row per style `style [S, D]` → `[S·P, F]`, style-major.
    ///
    /// Every point of a style shares its style row, so `W [f, s] + b = W_f f + (W_s s + b)`:
    /// the product over the points is taken once for all styles, with a `[P, F]` operand
    /// instead of a `[S·P, F + D]` concatenation; the style's part folds into the bias.
    pub fn forward(&self, features: Tensor<2>, style: Tensor<2>) -> Tensor<2> {
        let [p, d_f] = features.dims();
        let [s, d_s] = style.dims();
        let w = self.fuse.weight.val();
        let (w_f, w_s) = (w.clone().slice([0..d_f]), w.slice([d_f..d_f + d_s]));
        let mut bias = style.matmul(w_s);
        if let Some(b) = &self.fuse.bias {
            bias = bias + b.val().unsqueeze::<2>();
        }
        let (mixed, features) = if s == 1 {
            (
                relu(dense_with(features.clone(), w_f, bias.reshape([d_f]))),
                features,
            )
        } else {
            let zero = Tensor::zeros([d_f], &w_f.device());
            let product = dense_with(features.clone(), w_f, zero).unsqueeze::<3>();
            let mixed = relu(product.expand([s, p, d_f]) + bias.reshape([s, 1, d_f]));
            let features = features.unsqueeze::<3>().expand([s, p, d_f]);
            (mixed.reshape([s * p, d_f]), features.reshape([s * p, d_f]))
        };
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
            let style = Tensor::<2>::random([s + 1, 4], Distribution::Normal(s as f64, 1.0), &d);
            let out = am.forward(f.clone(), style);
            let f = f
                .clone()
                .unsqueeze::<3>()
                .expand([s + 1, 10, 8])
                .reshape([(s + 1) * 10, 8]);
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
        let style = Tensor::<2>::random([1, 4], Distribution::Default, &d);
        let grads = am.forward(f, style).square().sum().backward();
        let g = am.gamma.val().grad(&grads).expect("γ has a gradient");
        assert!(g.abs().sum().into_scalar::<f32>() > 0.0);
    }

    /// The style folded into the bias is the paper's `relu(W [f, s] + b)` on the concatenation,
    /// in value and in every gradient, for one style and for three sharing the features.
    #[test]
    fn the_folded_style_is_the_concatenated_layer() {
        let d = Device::flex().autodiff();
        d.seed(8);
        for (s, blend) in [(1, true), (3, true), (2, false)] {
            let (p, d_f, d_s) = (37, 24, 5);
            let mut am = AmalgamationConfig::new(d_f, d_s).with_blend(blend).init(&d);
            am.gamma = Param::from_tensor(Tensor::from_floats([0.3], &d));
            let f = Tensor::<2>::random([p, d_f], Distribution::Default, &d).require_grad();
            let style =
                Tensor::<2>::random([s, d_s], Distribution::Normal(0.0, 1.0), &d).require_grad();
            let target = Tensor::<2>::random([s * p, d_f], Distribution::Default, &d);
            let loss = |out: Tensor<2>| (out - target.clone()).square().sum();

            let folded = am.forward(f.clone(), style.clone());
            let g1 = loss(folded.clone()).backward();

            let rows = |t: Tensor<2>, n: usize| {
                let w = t.dims()[1];
                t.unsqueeze::<3>().expand([n, p, w]).reshape([n * p, w])
            };
            let per_style = style.clone().reshape([s, 1, d_s]).expand([s, p, d_s]);
            let cat = Tensor::cat(vec![rows(f.clone(), s), per_style.reshape([s * p, d_s])], 1);
            let w = am.fuse.weight.val();
            let b = am.fuse.bias.as_ref().unwrap().val();
            let mut reference = relu(cat.matmul(w) + b.unsqueeze::<2>());
            if blend {
                reference = rows(f.clone(), s) * 0.3 + reference * 0.7;
            }
            let g2 = loss(reference.clone()).backward();

            let gap = |a: Tensor<2>, b: Tensor<2>| {
                let scale = b.clone().abs().max().into_scalar::<f32>().max(1e-6);
                (a - b).abs().max().into_scalar::<f32>() / scale
            };
            assert!(gap(folded, reference) < 1e-5, "values, {s} styles");
            for (name, a, b) in [
                ("features", f.grad(&g1), f.grad(&g2)),
                ("style", style.grad(&g1), style.grad(&g2)),
                (
                    "weight",
                    am.fuse.weight.val().grad(&g1),
                    am.fuse.weight.val().grad(&g2),
                ),
            ] {
                let (a, b) = (a.expect(name), b.expect(name));
                let e = gap(a, b);
                assert!(e < 1e-5, "{name} gradient off by {e}, {s} styles");
            }
            let gb = |g| am.fuse.bias.as_ref().unwrap().val().grad(g).unwrap();
            let e = gap(gb(&g1).unsqueeze(), gb(&g2).unsqueeze());
            assert!(e < 1e-5, "bias gradient off by {e}, {s} styles");
        }
    }
}
