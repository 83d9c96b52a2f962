//! Style Implicit Module: style code → style features.
//!
//! As in the authors' NeRF code the code can be concatenated at every layer and an encoded
//! position can enter at layer 2, so that style features may vary over space.

use crate::kernels::dense::{dense, dense_with};
use crate::kernels::dense_chain::dense_chain_with;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Configuration of a [`Sim`].
#[derive(Config, Debug)]
pub struct SimConfig {
    /// Length of the style code (number of styles).
    pub d_code: usize,
    /// Hidden and output width.
    #[config(default = 64)]
    pub d_hidden: usize,
    /// Number of linear layers (ReLU between them, the last one linear).
    #[config(default = 2)]
    pub depth: usize,
    /// Concatenate the code again before every layer (authors' NeRF SIM) or only at the first.
    #[config(default = false)]
    pub code_every_layer: bool,
    /// Width of an encoded position entering before layer 2 (0: none).
    #[config(default = 0)]
    pub d_position: usize,
}

/// Style Implicit Module.
#[derive(Module, Debug)]
pub struct Sim {
    /// The layers, first to last.
    pub layers: Vec<Linear>,
    /// See [`SimConfig::code_every_layer`].
    pub code_every_layer: bool,
    /// See [`SimConfig::d_position`].
    pub d_position: usize,
}

impl SimConfig {
    /// Builds the module.
    pub fn init(&self, device: &Device) -> Sim {
        let layers = (0..self.depth.max(1))
            .map(|i| {
                let mut d_in = if i == 0 { self.d_code } else { self.d_hidden };
                if i > 0 && self.code_every_layer {
                    d_in += self.d_code;
                }
                if i == 1 {
                    d_in += self.d_position;
                }
                LinearConfig::new(d_in, self.d_hidden).init(device)
            })
            .collect();
        Sim {
            layers,
            code_every_layer: self.code_every_layer,
            d_position: self.d_position,
        }
    }
}

impl Sim {
    /// How many styles its codes select among.
    pub fn n_styles(&self) -> usize {
        self.layers[0].weight.dims()[0]
    }

    /// Output width.
    pub fn d_out(&self) -> usize {
        self.layers.last().map(|l| l.weight.dims()[1]).unwrap_or(0)
    }

    /// `codes [N, d_code]` (and `position [N, d_position]` when configured) → `[N, d_hidden]`.
    pub fn forward(&self, codes: Tensor<2>, position: Option<Tensor<2>>) -> Tensor<2> {
        let last = self.layers.len() - 1;
        let mut h = codes.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if i > 0 {
                let mut parts = vec![h];
                if self.code_every_layer {
                    parts.push(codes.clone());
                }
                if i == 1
                    && let Some(p) = &position
                {
                    parts.push(p.clone());
                }
                h = if parts.len() == 1 {
                    parts.pop().expect("one part")
                } else {
                    Tensor::cat(parts, 1)
                };
            }
            h = dense(layer, h);
            if i < last {
                h = relu(h);
            }
        }
        h
    }
}

impl Sim {
    /// [`Self::forward`] of every style at every position: `codes [S, d_code]` and `position
    /// [N, d_position]` → `[S·N, d_hidden]`, style-major. The same values, without its work
    /// per row that only depends on the style: the first layer sees the code alone (one row
    /// per style), and a code's share of every later layer is a bias of its style. The
    /// position's share of layer 2 is computed once for all styles. In a stylized render this
    /// is a quarter of the SIM's products and every copy of the code into each row.
    pub fn forward_per_style(&self, codes: Tensor<2>, position: Tensor<2>) -> Tensor<2> {
        let [s, k] = codes.dims();
        let n = position.dims()[0];
        if self.layers.len() < 2 || self.d_position == 0 {
            let rows = codes
                .reshape([s, 1, k])
                .expand([s, n, k])
                .reshape([s * n, k]);
            let p = self.d_position.max(1);
            let position = (self.d_position > 0).then(|| {
                position
                    .unsqueeze_dim::<3>(0)
                    .expand([s, n, p])
                    .reshape([s * n, p])
            });
            return self.forward(rows, position);
        }
        let last = self.layers.len() - 1;
        // What each later layer adds for a style's code: `code·W_code + b`, `[S, out]`.
        let code_bias = |layer: &Linear, from: usize| -> Tensor<2> {
            let w = layer.weight.val();
            let o = w.dims()[1];
            let b = layer.bias.as_ref().map(|b| b.val().reshape([1, o]));
            let mut c = if self.code_every_layer {
                codes.clone().matmul(w.slice([from..from + k, 0..o]))
            } else {
                Tensor::zeros([s, o], &w.device())
            };
            if let Some(b) = b {
                c = c + b;
            }
            c
        };
        // Layer 1 on the code alone.
        let h0 = relu(dense(&self.layers[0], codes.clone()));
        let wd = h0.dims()[1];
        // Layer 2: `[h0, code, position]`; all but the position is per style.
        let l1 = &self.layers[1];
        let w1 = l1.weight.val();
        let o = w1.dims()[1];
        let from_position = wd + if self.code_every_layer { k } else { 0 };
        let constant = h0.matmul(w1.clone().slice([0..wd, 0..o])) + code_bias(l1, wd);
        let w_position = w1.slice([from_position..from_position + self.d_position, 0..o]);
        if s == 1 {
            // One style: every layer from the second is the position's product plus a bias,
            // a chain (fused where no gradient is asked for).
            let mut chain = vec![(w_position, constant.reshape([o]), last > 1)];
            let mut d_in = o;
            for (i, layer) in self.layers.iter().enumerate().skip(2) {
                let w = layer.weight.val();
                let o = w.dims()[1];
                let bias = code_bias(layer, d_in).reshape([o]);
                chain.push((w.slice([0..d_in, 0..o]), bias, i < last));
                d_in = o;
            }
            return dense_chain_with(position, chain);
        }
        let mut h = per_style(position, w_position, constant, s, true);
        for (i, layer) in self.layers.iter().enumerate().skip(1) {
            if i > 1 {
                let w = layer.weight.val();
                let (d_in, o) = (h.dims()[1], w.dims()[1]);
                h = per_style(
                    h,
                    w.slice([0..d_in, 0..o]),
                    code_bias(layer, d_in),
                    s,
                    false,
                );
            }
            if i < last {
                h = relu(h);
            }
        }
        h
    }
}

/// `x·w` plus a bias per style `[S, O]`: `x` is shared by the styles (`[N, I]`, `shared`) or
/// already per style (`[S·N, I]`); the result is `[S·N, O]`, style-major. One style's bias
/// is the layer's own.
fn per_style(x: Tensor<2>, w: Tensor<2>, bias: Tensor<2>, s: usize, shared: bool) -> Tensor<2> {
    let o = w.dims()[1];
    if s == 1 {
        return dense_with(x, w, bias.reshape([o]));
    }
    let device = w.device();
    let y = dense_with(x, w, Tensor::zeros([o], &device));
    let rows = y.dims()[0];
    let n = if shared { rows } else { rows / s };
    let y = if shared {
        y.reshape([1, n, o])
    } else {
        y.reshape([s, n, o])
    };
    (y + bias.reshape([s, 1, o])).reshape([s * n, o])
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn code_at_every_layer_and_position_at_layer_two() {
        let d = Device::flex();
        d.seed(4);
        let sim = SimConfig::new(3)
            .with_d_hidden(16)
            .with_depth(4)
            .with_code_every_layer(true)
            .with_d_position(7)
            .init(&d);
        let inputs: Vec<usize> = sim.layers.iter().map(|l| l.weight.dims()[0]).collect();
        assert_eq!(inputs, [3, 16 + 3 + 7, 16 + 3, 16 + 3]);
        let codes = Tensor::<2>::from_floats([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], &d);
        let pos = Tensor::<2>::random([2, 7], Distribution::Default, &d);
        let y = sim.forward(codes, Some(pos));
        assert_eq!(y.dims(), [2, 16]);
        // Same code, different positions: different style features (they vary over space).
        let rows = y.clone().slice([0..1]) - y.slice([1..2]);
        assert!(rows.abs().sum().into_scalar::<f32>() > 1e-4);
    }

    /// `forward_per_style` against `forward` on every (style, position) row: values and the
    /// gradients of every layer and of the position, for one style and for two, with the code
    /// at every layer and only at the first.
    #[test]
    fn per_style_work_done_once_gives_every_rows_values_and_gradients() {
        let d = Device::flex().autodiff();
        d.seed(6);
        for (every, codes) in [
            (true, vec![[1.0f32, 0.0]]),
            (true, vec![[1.0, 0.0], [0.3, 0.7]]),
            (false, vec![[0.0, 1.0], [1.0, 0.0]]),
        ] {
            let sim = SimConfig::new(2)
                .with_d_hidden(16)
                .with_depth(4)
                .with_code_every_layer(every)
                .with_d_position(5)
                .init(&d);
            let s = codes.len();
            let codes = Tensor::<2>::from_floats(TensorData::new(codes.concat(), [s, 2]), &d);
            let pos = Tensor::<2>::random([9, 5], Distribution::Default, &d).require_grad();
            let probe = Tensor::<2>::random([s * 9, 16], Distribution::Default, &d);
            let got = sim.forward_per_style(codes.clone(), pos.clone());
            let rows = codes
                .reshape([s, 1, 2])
                .expand([s, 9, 2])
                .reshape([s * 9, 2]);
            let pos_rows = pos
                .clone()
                .unsqueeze_dim::<3>(0)
                .expand([s, 9, 5])
                .reshape([s * 9, 5]);
            let want = sim.forward(rows, Some(pos_rows));
            let scale = want.clone().abs().max().into_scalar::<f32>();
            let diff = (got.clone() - want.clone())
                .abs()
                .max()
                .into_scalar::<f32>();
            assert!(diff <= 1e-5 * scale, "{s} styles, every {every}: {diff}");
            let g_got = (got * probe.clone()).sum().backward();
            let g_want = (want * probe).sum().backward();
            let close = |a: Tensor<2>, b: Tensor<2>, what: &str| {
                let scale = b.clone().abs().max().into_scalar::<f32>().max(1e-6);
                let diff = (a - b).abs().max().into_scalar::<f32>();
                assert!(
                    diff <= 1e-5 * scale,
                    "{what}, {s} styles, every {every}: {diff}"
                );
            };
            close(
                pos.grad(&g_got).unwrap(),
                pos.grad(&g_want).unwrap(),
                "position",
            );
            for (i, l) in sim.layers.iter().enumerate() {
                let w = l.weight.val();
                close(
                    w.grad(&g_got).unwrap(),
                    w.grad(&g_want).unwrap(),
                    &format!("w{i}"),
                );
                let b = l.bias.as_ref().unwrap().val();
                close(
                    b.grad(&g_got).unwrap().reshape([1, 16]),
                    b.grad(&g_want).unwrap().reshape([1, 16]),
                    &format!("b{i}"),
                );
            }
        }
    }

    #[test]
    fn different_codes_give_different_features() {
        let d = Device::flex();
        d.seed(5);
        let sim = SimConfig::new(2).init(&d);
        let y = sim.forward(Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0]], &d), None);
        let rows = y.clone().slice([0..1]) - y.slice([1..2]);
        assert!(rows.abs().sum().into_scalar::<f32>() > 1e-4);
    }
}
