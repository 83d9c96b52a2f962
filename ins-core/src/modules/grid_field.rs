//! The fast content module for 3D: a multiresolution hash grid and a one-hidden-layer MLP that
//! outputs a raw density and 15 geometry features (instant-ngp's density network).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use super::hash_grid::{HashGrid, HashGridConfig};
use crate::kernels::dense_chain::dense_chain;

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
        let out = dense_chain(h, &[(&self.hidden, true), (&self.out, false)]);
        let [n, w] = out.dims();
        let sigma = out.clone().slice([0..n, 0..1]).reshape([n]);
        (sigma, out.slice([0..n, 1..w]))
    }

    /// The same module with its raw density lowered by `by` everywhere (the output bias): a
    /// fresh field that starts nearly transparent, `exp(−by)` times as dense.
    pub fn with_density_offset(mut self, by: f32) -> Self {
        if let Some(bias) = self.out.bias.take() {
            let b = bias.val();
            let device = b.device();
            let n = b.dims()[0];
            let mut shift = vec![0f32; n];
            shift[0] = -by;
            let shifted = (b + Tensor::<1>::from_floats(shift.as_slice(), &device)).detach();
            self.out.bias = Some(burn::module::Param::from_tensor(shifted));
        }
        self
    }

    /// Width of the features.
    pub fn d_features(&self) -> usize {
        self.out.weight.dims()[1] - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn a_density_offset_lowers_the_raw_density_alone_and_stays_trainable() {
        let d = Device::flex().autodiff();
        d.seed(3);
        let config = GridGeometryConfig::new(HashGridConfig::new().with_log2_table(10));
        let g = config.init([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], &d);
        let x = Tensor::<2>::random([16, 3], Distribution::Uniform(-1.0, 1.0), &d);
        let (raw, features) = g.forward(x.clone());
        let g = g.with_density_offset(4.0);
        let (raw2, features2) = g.forward(x);
        let shift = (raw - raw2.clone())
            .inner()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(shift.iter().all(|s| (s - 4.0).abs() < 1e-5), "{shift:?}");
        let same = (features - features2).abs().max().into_scalar::<f32>();
        assert_eq!(same, 0.0);
        let grads = raw2.sum().backward();
        let bias = g.out.bias.as_ref().unwrap().val();
        assert!(
            bias.grad(&grads).is_some(),
            "the shifted bias lost its gradient"
        );
    }
}
