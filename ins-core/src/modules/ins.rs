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
    /// The content features are computed once and shared by every style in the batch.
    pub fn forward(&self, coords: Tensor<2>, codes: Tensor<2>) -> Tensor<3> {
        let [p, _] = coords.dims();
        let [s, _] = codes.dims();
        let f = self.cim.features(coords);
        let d_f = f.dims()[1];
        let style = self.sim.forward(codes, None);
        let d_s = style.dims()[1];
        let (f, style) = if s == 1 {
            (f, style.expand([p, d_s]))
        } else {
            (
                f.unsqueeze::<3>().expand([s, p, d_f]).reshape([s * p, d_f]),
                style
                    .reshape([s, 1, d_s])
                    .expand([s, p, d_s])
                    .reshape([s * p, d_s]),
            )
        };
        let h = self.am.forward(f, style);
        sigmoid(self.head.forward(h)).reshape([s, p, 3])
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
