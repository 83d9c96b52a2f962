//! Multiresolution hash encoding (instant-ngp): L levels of F learned features each, looked up
//! by trilinear interpolation at geometrically growing resolutions. Its kernels (on slices, as
//! CubeCL kernels, as a Burn op) are in [`crate::kernels::hash_grid`].

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::Distribution;

pub use crate::kernels::hash_grid::GridShape;
use crate::kernels::hash_grid::{op, reference};

/// Configuration of a [`HashGrid`].
#[derive(Config, Debug)]
pub struct HashGridConfig {
    /// Levels L.
    #[config(default = 16)]
    pub levels: u32,
    /// Features per level F.
    #[config(default = 2)]
    pub features: u32,
    /// log2 of the table size T per level (≤ 19).
    #[config(default = 17)]
    pub log2_table: u32,
    /// Coarsest resolution.
    #[config(default = 16)]
    pub base_resolution: u32,
    /// Finest resolution (≤ 2047).
    #[config(default = 1024)]
    pub max_resolution: u32,
}

impl HashGridConfig {
    /// The sizes as the kernels take them.
    pub fn shape(&self) -> GridShape {
        GridShape {
            levels: self.levels,
            features: self.features,
            log2_table: self.log2_table,
            base_resolution: self.base_resolution,
            max_resolution: self.max_resolution,
        }
    }

    /// Checks the limits the index arithmetic relies on.
    pub fn validate(&self) -> Result<(), String> {
        if self.levels == 0 || self.features == 0 {
            return Err("hash grid: levels and features must be positive".into());
        }
        if !(4..=19).contains(&self.log2_table) {
            return Err(format!(
                "hash grid: log2_table {} is outside 4..=19",
                self.log2_table
            ));
        }
        if self.base_resolution == 0
            || self.max_resolution < self.base_resolution
            || self.max_resolution > 2047
        {
            return Err(format!(
                "hash grid: resolutions {}..{} must satisfy 1 ≤ base ≤ max ≤ 2047",
                self.base_resolution, self.max_resolution
            ));
        }
        Ok(())
    }

    /// Builds the grid with table entries drawn from U(−1e-4, 1e-4) (instant-ngp).
    pub fn init(&self, device: &Device) -> HashGrid {
        let shape = self.shape();
        let rows = shape.layout().total_rows();
        HashGrid {
            table: Param::from_tensor(Tensor::random(
                [rows, self.features as usize],
                Distribution::Uniform(-1e-4, 1e-4),
                device,
            )),
            shape,
        }
    }
}

/// A learned multiresolution hash grid.
#[derive(Module, Debug)]
pub struct HashGrid {
    /// All levels' feature vectors, `[rows, F]`.
    pub table: Param<Tensor<2>>,
    /// Sizes.
    #[module(skip)]
    pub shape: GridShape,
}

impl HashGrid {
    /// Width of the encoding, L·F.
    pub fn d_out(&self) -> usize {
        self.shape.d_out()
    }

    /// `positions [N, 3]` in `[0, 1]³` → `[N, L·F]`, differentiable in the table and positions.
    pub fn forward(&self, positions: Tensor<2>) -> Tensor<2> {
        let table = self.table.val();
        if op::kernel_device(&positions.device()) {
            op::encode_kernel(positions, table, self.shape)
        } else {
            reference::encode(positions, table, self.shape)
        }
    }

    /// `∂encoding/∂positions`, `[N, L·F, 3]`, differentiable in the table.
    pub fn jacobian(&self, positions: Tensor<2>) -> Tensor<3> {
        let table = self.table.val();
        if op::kernel_device(&positions.device()) {
            op::jacobian_kernel(positions, table, self.shape)
        } else {
            reference::jacobian(positions, table, self.shape)
        }
    }
}
