//! A multiresolution hash grid and a small MLP over `[x, enc(x)]`: an SDF fast on a CPU.

use burn::nn::Linear;
use burn::prelude::*;

use super::dual::Dual;
use super::{
    BETA, distance_and_features, distance_features_and_gradient, distance_head, linear_normal,
};
use crate::kernels::dense::dense;
use crate::kernels::softplus::softplus;
use crate::modules::hash_grid::{HashGrid, HashGridConfig};

/// Configuration of an [`SdfGrid`].
#[derive(Config, Debug)]
pub struct SdfGridConfig {
    /// The hash grid.
    pub grid: HashGridConfig,
    /// Hidden width.
    #[config(default = 64)]
    pub d_hidden: usize,
    /// Width of the feature vector.
    #[config(default = 15)]
    pub d_features: usize,
    /// Radius of the initial sphere.
    #[config(default = 0.5)]
    pub radius: f64,
}

/// Hash grid + MLP over `[x, enc(x)]` → (signed distance, features), over the box `[-b, b]³`.
#[derive(Module, Debug)]
pub struct SdfGrid {
    /// The encoding.
    pub grid: HashGrid,
    /// Hidden layer over `[x, enc(x)]`.
    pub hidden: Linear,
    /// Output layer: distance then features.
    pub out: Linear,
    /// Half side of the box the grid covers.
    pub bound: f32,
    /// Radius of the sphere the field starts as.
    pub radius: f32,
}

impl SdfGridConfig {
    /// Builds the network over `[-bound, bound]³`, starting as the sphere of radius `radius`.
    pub fn init(&self, bound: f32, device: &Device) -> SdfGrid {
        let grid = self.grid.init(device);
        let d_in = 3 + grid.d_out();
        let h = self.d_hidden;
        let hidden = linear_normal(
            d_in,
            h,
            0.0,
            (2.0f64).sqrt() / (h as f64).sqrt(),
            0.0,
            device,
        );
        let out = distance_head(h, 1 + self.d_features, device);
        SdfGrid {
            grid,
            hidden,
            out,
            bound,
            radius: self.radius as f32,
        }
    }
}

impl SdfGrid {
    fn unit(&self, x: Tensor<2>) -> Tensor<2> {
        x.div_scalar(2.0 * self.bound).add_scalar(0.5)
    }

    /// `x [N, 3]` → signed distance `[N]` and features `[N, F]`.
    pub fn forward(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>) {
        let enc = self.grid.forward(self.unit(x.clone()));
        let h = softplus(
            dense(&self.hidden, Tensor::cat(vec![x.clone(), enc], 1)),
            BETA,
        );
        let out = dense(&self.out, h);
        distance_and_features(x, self.radius, out)
    }

    /// Value, features and the exact gradient `∇f [N, 3]` (forward mode through the grid's
    /// Jacobian and the MLP), differentiable in the parameters.
    pub fn forward_with_gradient(&self, x: Tensor<2>) -> (Tensor<1>, Tensor<2>, Tensor<2>) {
        let [n, _] = x.dims();
        let device = x.device();
        let u = self.unit(x.clone());
        let enc = self.grid.forward(u.clone());
        let jac = self.grid.jacobian(u); // ∂enc/∂u [N, L·F, 3], u = x / scale + ½
        let e = enc.dims()[1];
        // Tangents along u rather than x, `[scale·e_k, ∂enc/∂u_k]` = scale × `[e_k, ∂enc/∂x_k]`,
        // divided back out of the gradient [N, 3]: scaling the Jacobian itself put a
        // single-threaded pass over its permuted layout into every backward.
        let scale = 2.0 * self.bound;
        let eye = Tensor::<2>::eye(3, &device).mul_scalar(scale); // [3, 3]
        let t_x = eye.unsqueeze_dim::<3>(1).expand([3, n, 3]);
        let t_enc = jac.permute([2, 0, 1]); // [3, N, L·F]
        let t = Tensor::cat(vec![t_x, t_enc], 2).reshape([3 * n, 3 + e]);
        let d = Dual {
            h: Tensor::cat(vec![x.clone(), enc], 1),
            t,
        };
        let out = d.linear(&self.hidden).softplus().output(&self.out);
        distance_features_and_gradient(x, self.radius, out, scale)
    }
}
