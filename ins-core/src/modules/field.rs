//! Radiance fields: a geometry module (position → raw density and features) and a colour head
//! (features and view direction → RGB). The geometry is either the fast hash grid or the
//! paper's NeRF MLP, chosen per run; both sit behind one enum so a run is one concrete type.

use burn::prelude::*;
use burn::tensor::activation::relu;
use serde::{Deserialize, Serialize};

use super::color_head::ColorHead;
use super::grid_field::GridGeometry;
use super::mlp_field::MlpGeometry;

/// Which content module a 3D run uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum CimKind {
    /// Multiresolution hash grid + small MLPs (fast on a CPU).
    #[default]
    Grid,
    /// NeRF's 8×256 MLP with coarse and fine networks (the paper's).
    Mlp,
}

impl std::str::FromStr for CimKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "grid" => Ok(Self::Grid),
            "mlp" | "nerf" => Ok(Self::Mlp),
            _ => Err(format!("unknown --cim {s:?} (expected grid or mlp)")),
        }
    }
}

impl std::fmt::Display for CimKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Grid => "grid",
            Self::Mlp => "mlp",
        })
    }
}

/// A geometry module.
#[derive(Module, Debug)]
pub enum Geometry {
    /// Hash grid.
    Grid(GridGeometry),
    /// NeRF MLP.
    Mlp(MlpGeometry),
}

impl Geometry {
    /// `x [N, 3]` → raw (pre-activation) density `[N]` and features `[N, F]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        match self {
            Self::Grid(g) => g.forward(x),
            Self::Mlp(m) => m.forward(x),
        }
    }

    /// Width of the features.
    pub fn d_features(&self) -> usize {
        match self {
            Self::Grid(g) => g.d_features(),
            Self::Mlp(m) => m.d_features(),
        }
    }

    /// Density from raw density: `exp` truncated at e^15 for the grid (instant-ngp; its
    /// gradient stops there), ReLU for the MLP (NeRF).
    pub fn activate(&self, raw: Tensor<1>) -> Tensor<1> {
        match self {
            Self::Grid(_) => raw.clamp_max(15.0).exp(),
            Self::Mlp(_) => relu(raw),
        }
    }
}

/// Geometry and colour of one radiance field.
#[derive(Module, Debug)]
pub struct Field {
    /// Position → raw density and features.
    pub geometry: Geometry,
    /// Features and view direction → colour.
    pub color: ColorHead,
}

impl Field {
    /// Density `[N]` (activated) and colour `[N, 3]` at positions `x [N, 3]` seen along
    /// directions encoded by [`ColorHead::encode_dirs`](super::color_head::ColorHead::encode_dirs).
    pub fn forward(&self, x: Tensor<2>, encoded_dirs: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        let (raw, features) = self.geometry.forward(x);
        (
            self.geometry.activate(raw),
            self.color.forward(features, encoded_dirs),
        )
    }

    /// Density only (for occupancy grids and geometry checks).
    pub fn density(&self, x: Tensor<2>) -> Tensor<1> {
        let (raw, _) = self.geometry.forward(x);
        self.geometry.activate(raw)
    }
}
