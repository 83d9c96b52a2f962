//! [`Ins`]: SIM + CIM + AM + an RGB head, for coordinate → colour representations (images).
//!
//! This is the library API for custom INRs: bring any [`ContentModule`] and the same trainer,
//! losses and checkpoints work. NeRF and IDR compose the same three modules differently (they
//! render along rays), in `ins-models`.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

use super::am::{Amalgamation, AmalgamationConfig};
use super::cim::ContentModule;
use super::sim::{Sim, SimConfig};
use crate::kernels::{dense::dense, dense_bf16};
use crate::train::groups::{GroupSpec, Optimizable};

/// SIM + CIM + AM + linear RGB head with a sigmoid.
#[derive(Module, Debug)]
pub struct Ins<C> {
    /// Style Implicit Module.
    pub sim: Sim,
    /// Content Implicit Module.
    pub cim: C,
    /// Amalgamation Module.
    pub am: Amalgamation,
    /// Features → RGB.
    pub head: Linear,
}

impl<C: ContentModule> Ins<C> {
    /// Composes a content module with a fresh SIM, AM (γ = 1) and head.
    pub fn new(cim: C, sim: &SimConfig, blend: bool, device: &Device) -> Self {
        let d = cim.d_features();
        let sim = sim.init(device);
        let am = AmalgamationConfig::new(d, sim.d_out())
            .with_blend(blend)
            .init(device);
        Self {
            sim,
            cim,
            am,
            head: LinearConfig::new(d, 3).init(device),
        }
    }

    /// Number of styles the SIM was built for.
    pub fn n_styles(&self) -> usize {
        self.sim.layers[0].weight.dims()[0]
    }

    /// `coords [P, d]`, `codes [S, n_styles]` → RGB in [0, 1], `[S, P, 3]`.
    ///
    /// The content features are computed once and shared by every style in the batch. The
    /// AM's `[P, 256] → 256` product runs in bf16 on flex where the CPU has AVX-512 BF16 (unless
    /// `--precision f32` or `INS_DISABLE_BF16` says otherwise), as the CIM's hidden layers do:
    /// it was a sixth of a stylizing step in f32 (docs/measurements.md); the SIM and the head
    /// stay f32.
    pub fn forward(&self, coords: Tensor<2>, codes: Tensor<2>) -> Tensor<3> {
        let [p, _] = coords.dims();
        let [s, _] = codes.dims();
        let f = self.cim.features(coords);
        let style = self.sim.forward(codes, None);
        let h = {
            let _precision = dense_bf16::scope(true);
            self.am.forward(f, style)
        };
        sigmoid(dense(&self.head, h)).reshape([s, p, 3])
    }

    /// `coords [P, d]` → RGB `[P, 3]` through the content path alone (CIM and head): what
    /// [`Ins::forward`] gives, bit for bit, while the AM is the identity (γ = 1, as through the
    /// fitting phase, which freezes it), without the SIM's and the AM's work.
    pub fn forward_content(&self, coords: Tensor<2>) -> Tensor<2> {
        sigmoid(dense(&self.head, self.cim.features(coords)))
    }
}

impl<C: ContentModule> Optimizable for Ins<C> {
    /// The RGB head is its own group, so freezing the amalgamation leaves colour trainable.
    fn groups(&self) -> Vec<GroupSpec> {
        vec![
            GroupSpec::new("sim", &["sim"]),
            GroupSpec::new("cim", &["cim"]),
            GroupSpec::new("am", &["am"]),
            GroupSpec::new("head", &["head"]),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modules::cim::{SirenCim, SirenCimConfig};
    use burn::module::Param;
    use burn::tensor::Distribution;

    fn host(t: Tensor<3>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// The AM's product runs in bf16 (where the CPU has AVX-512 BF16), exactly as a scope
    /// around the AM alone gives it, and in f32 under `forbid`; the content features and the
    /// head are not moved by it.
    #[test]
    fn the_am_product_runs_in_bf16_and_f32_under_forbid() {
        if !dense_bf16::available() {
            eprintln!("no AVX-512 BF16 here: nothing runs in bf16");
            return;
        }
        let d = Device::flex();
        d.seed(4);
        let cim = SirenCimConfig::new()
            .with_d_hidden(64)
            .with_depth(2)
            .init(&d);
        let mut ins = Ins::new(cim, &SimConfig::new(2).with_d_hidden(16), true, &d);
        // γ away from 1, so the AM's product reaches the colour.
        ins.am.gamma = Param::from_tensor(Tensor::from_floats([0.4], &d));
        let x = Tensor::<2>::random([90, 2], Distribution::Uniform(-1.0, 1.0), &d);
        let codes = Tensor::<2>::from_floats([[1.0, 0.0], [0.3, 0.7]], &d);
        let composed = |am_bf16: bool| {
            let f = ins.cim.features(x.clone());
            let style = ins.sim.forward(codes.clone(), None);
            let h = {
                let _p = dense_bf16::scope(am_bf16);
                ins.am.forward(f, style)
            };
            sigmoid(dense(&ins.head, h)).reshape([2, 90, 3])
        };
        let mixed = host(ins.forward(x.clone(), codes.clone()));
        assert_eq!(mixed, host(composed(true)), "the AM not in bf16");
        let f32_am = host(composed(false));
        let err = mixed
            .iter()
            .zip(&f32_am)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err > 0.0 && err < 0.01, "bf16 AM against f32: {err}");
        let forbidden = {
            let _f32 = dense_bf16::forbid();
            host(ins.forward(x.clone(), codes.clone()))
        };
        let all_f32 = {
            let _f32 = dense_bf16::forbid();
            host(composed(true))
        };
        assert_eq!(forbidden, all_f32, "forbid left the AM in bf16");
    }

    /// While the AM is the identity (γ = 1), the content path alone gives `forward`'s colours
    /// and the content module's gradients bit for bit; with γ moved it does not.
    #[test]
    fn the_content_path_is_forward_while_the_am_is_the_identity() {
        let d = Device::flex().autodiff();
        d.seed(5);
        let cim = SirenCimConfig::new()
            .with_d_hidden(64)
            .with_depth(2)
            .init(&d);
        let mut ins = Ins::new(cim, &SimConfig::new(1).with_d_hidden(16), true, &d);
        let x = Tensor::<2>::random([50, 2], Distribution::Uniform(-1.0, 1.0), &d);
        let code = Tensor::<2>::from_floats([[1.0]], &d);
        let target = Tensor::<2>::random([50, 3], Distribution::Default, &d);
        let run = |ins: &Ins<SirenCim>, whole: bool| {
            let rgb = if whole {
                ins.forward(x.clone(), code.clone()).reshape([50, 3])
            } else {
                ins.forward_content(x.clone())
            };
            let grads = (rgb.clone() - target.clone()).square().sum().backward();
            let w = ins.cim.layers[1].linear.weight.val();
            let g = w.grad(&grads).expect("the CIM has a gradient");
            (
                host(rgb.unsqueeze()),
                g.into_data().try_to_vec::<f32>().unwrap(),
            )
        };
        assert_eq!(run(&ins, true), run(&ins, false), "γ = 1");
        ins.am.gamma = Param::from_tensor(Tensor::from_floats([0.9], &d));
        assert_ne!(run(&ins, true).0, run(&ins, false).0, "γ = 0.9");
    }
}
