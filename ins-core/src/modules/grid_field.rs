//! The fast content module for 3D: a multiresolution hash grid and a one-hidden-layer MLP that
//! outputs a raw density and 15 geometry features (instant-ngp's density network).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use super::dense_op::dense;
use super::hash_grid::{HashGrid, HashGridConfig};

/// Configuration of a [`GridGeometry`].
#[derive(Config, Debug)]
pub struct GridGeometryConfig {
    /// The hash grid.
    pub grid: HashGridConfig,
    /// Hidden width of the density MLP.
    #[config(default = 64)]
    pub d_hidden: usize,
    /// Width of the geometry features passed on (the density is one more output).
    #[config(default = 15)]
    pub d_features: usize,
}

/// Hash grid → MLP → (raw density, features), over a box of the scene.
#[derive(Module, Debug)]
pub struct GridGeometry {
    /// The encoding.
    pub grid: HashGrid,
    /// Hidden layer.
    pub hidden: Linear,
    /// Output layer: density then features.
    pub out: Linear,
    /// The box `[min, max]` mapped to the grid's unit cube.
    #[module(skip)]
    pub aabb: [f32; 6],
}

impl GridGeometryConfig {
    /// Builds the module over the box `aabb = [min_x, min_y, min_z, max_x, max_y, max_z]`.
    pub fn init(&self, aabb: [f32; 6], device: &Device) -> GridGeometry {
        let grid = self.grid.init(device);
        GridGeometry {
            hidden: LinearConfig::new(grid.d_out(), self.d_hidden).init(device),
            out: LinearConfig::new(self.d_hidden, 1 + self.d_features).init(device),
            grid,
            aabb,
        }
    }
}

impl GridGeometry {
    /// Positions `[N, 3]` in the box → the grid's `[0, 1]³`.
    pub fn normalize(&self, x: Tensor<2>) -> Tensor<2> {
        let device = x.device();
        let a = self.aabb;
        let min = Tensor::<1>::from_floats([a[0], a[1], a[2]], &device).reshape([1, 3]);
        let inv = Tensor::<1>::from_floats(
            [
                1.0 / (a[3] - a[0]),
                1.0 / (a[4] - a[1]),
                1.0 / (a[5] - a[2]),
            ],
            &device,
        )
        .reshape([1, 3]);
        (x - min) * inv
    }

    /// `x [N, 3]` → raw density `[N]` and features `[N, d_features]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        let h = self.grid.forward(self.normalize(x));
        let out = dense(&self.out, relu(dense(&self.hidden, h)));
        let [n, w] = out.dims();
        let sigma = out.clone().slice([0..n, 0..1]).reshape([n]);
        (sigma, out.slice([0..n, 1..w]))
    }

    /// Width of the features.
    pub fn d_features(&self) -> usize {
        self.out.weight.dims()[1] - 1
    }
}
