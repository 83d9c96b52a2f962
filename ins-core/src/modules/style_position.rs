//! Where a point is, as the SIM sees it: octaves of its position (the authors' SIM input) and,
//! optionally, a hash grid of the SIM's own. A painting's strokes are finer than any octave a
//! small MLP can combine; a grid of learned features in space can hold them, on the object, the
//! same from every view. The content module's own grid cannot: it also carries the density.

use burn::prelude::*;

use super::encoding::FourierEncoding;
use super::hash_grid::{HashGrid, HashGridConfig};
use super::sim::{Sim, SimConfig};

/// Learning-rate multiplier of the texture grid against the MLPs' rate: hash-grid entries each
/// see few samples per step and learn at about ten times an MLP's rate (instant-ngp's 1e-2
/// against 1e-3).
pub const TEXTURE_LR_MULT: f64 = 10.0;

/// Configuration of a [`StylePosition`].
#[derive(Config, Debug)]
pub struct StylePositionConfig {
    /// Octaves of the position encoding.
    #[config(default = 4)]
    pub position_freqs: usize,
    /// Finest resolution of the texture hash grid over the unit cube (0: no grid).
    #[config(default = 0)]
    pub grid_resolution: u32,
    /// log2 of the grid's table size per level.
    #[config(default = 17)]
    pub grid_log2_table: u32,
}

/// The SIM's view of a position.
#[derive(Module, Debug)]
pub struct StylePosition {
    /// Octaves of the position encoding.
    pub position_freqs: usize,
    /// The texture grid, where configured.
    pub grid: Option<HashGrid>,
}

impl StylePositionConfig {
    /// Builds the module (the grid's entries near 0, so its features start silent).
    pub fn init(&self, device: &Device) -> StylePosition {
        StylePosition {
            position_freqs: self.position_freqs,
            grid: (self.grid_resolution > 0).then(|| {
                HashGridConfig::new()
                    .with_levels(16)
                    .with_features(2)
                    .with_log2_table(self.grid_log2_table)
                    .with_base_resolution(16.min(self.grid_resolution))
                    .with_max_resolution(self.grid_resolution)
                    .init(device)
            }),
        }
    }
}

/// The SIM a scene variant stylizes with, and how it sees positions: the authors' SIM (4
/// layers `width` wide, the style code at every layer, the position from layer 2) reading
/// `position`. The position module is drawn first, then the SIM.
pub fn positional_sim(
    n_styles: usize,
    width: usize,
    position: &StylePositionConfig,
    device: &Device,
) -> (StylePosition, Sim) {
    let position = position.init(device);
    let sim = SimConfig::new(n_styles)
        .with_d_hidden(width)
        .with_depth(4)
        .with_code_every_layer(true)
        .with_d_position(position.d_out())
        .init(device);
    (position, sim)
}

impl StylePosition {
    /// Width of the encoding.
    pub fn d_out(&self) -> usize {
        FourierEncoding::new(self.position_freqs).d_out(3)
            + self.grid.as_ref().map_or(0, |g| g.d_out())
    }

    /// `unit [N, 3]` positions in `[-1, 1]³` → `[N, d_out]`: octaves, then grid features.
    pub fn encode(&self, unit: Tensor<2>) -> Tensor<2> {
        let octaves = FourierEncoding::new(self.position_freqs).encode(unit.clone());
        match &self.grid {
            None => octaves,
            Some(grid) => {
                let cube = unit.add_scalar(1.0).mul_scalar(0.5).clamp(0.0, 1.0);
                Tensor::cat(vec![octaves, grid.forward(cube)], 1)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn the_grid_widens_the_encoding_and_takes_gradients() {
        let d = Device::flex().autodiff();
        d.seed(2);
        let plain = StylePositionConfig::new().init(&d);
        assert_eq!(plain.d_out(), 27);
        let textured = StylePositionConfig::new()
            .with_grid_resolution(256)
            .with_grid_log2_table(12)
            .init(&d);
        assert_eq!(textured.d_out(), 27 + 32);
        let x = Tensor::<2>::random([64, 3], Distribution::Uniform(-1.0, 1.0), &d);
        let y = textured.encode(x);
        assert_eq!(y.dims(), [64, 59]);
        let grads = y.sum().backward();
        let table = textured.grid.as_ref().unwrap().table.val();
        assert!(table.grad(&grads).is_some(), "no gradient reached the grid");
    }
}
