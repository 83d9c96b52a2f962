//! IDR's rendering network: the colour of a surface point from its position, normal, the
//! viewing direction and the SDF network's features, `(x, n, v, f) → RGB`.

use burn::prelude::*;

use super::encoding::FourierEncoding;
use super::hash_grid::{HashGrid, HashGridConfig};
use super::mlp::RgbMlp;

/// Configuration of a [`SurfaceColor`].
#[derive(Config, Debug)]
pub struct SurfaceColorConfig {
    /// Width of the SDF features.
    pub d_features: usize,
    /// Hidden width (IDR: 512).
    #[config(default = 512)]
    pub d_hidden: usize,
    /// Hidden layers (IDR: 4).
    #[config(default = 4)]
    pub depth: usize,
    /// Octaves of the view-direction encoding (IDR: 4).
    #[config(default = 4)]
    pub dir_freqs: usize,
    /// An appearance hash grid over `[-1, 1]³` whose features join the input: texture finer
    /// than the SDF's own grid can hold without roughening the surface (none: IDR).
    #[config(default = "None")]
    pub grid: Option<HashGridConfig>,
}

/// `[x, n, enc(v), f]` → ReLU layers → sigmoid RGB.
#[derive(Module, Debug)]
pub struct SurfaceColor {
    /// Hidden ReLU layers and the linear RGB layer.
    pub mlp: RgbMlp,
    /// Octaves of the view-direction encoding.
    pub dir_freqs: usize,
    /// Appearance grid, when configured.
    pub grid: Option<HashGrid>,
}

impl SurfaceColorConfig {
    /// Builds the network.
    pub fn init(&self, device: &Device) -> SurfaceColor {
        let grid = self.grid.as_ref().map(|g| g.init(device));
        let d_grid = grid.as_ref().map_or(0, HashGrid::d_out);
        let d_in = 3 + 3 + FourierEncoding::new(self.dir_freqs).d_out(3) + self.d_features + d_grid;
        SurfaceColor {
            mlp: RgbMlp::new(d_in, self.d_hidden, self.depth, device),
            dir_freqs: self.dir_freqs,
            grid,
        }
    }
}

impl SurfaceColor {
    /// `x, normals, dirs [N, 3]`, `features [N, F]` → RGB `[N, 3]`; `x` inside `[-1, 1]³`.
    pub fn forward(
        &self,
        x: Tensor<2>,
        normals: Tensor<2>,
        dirs: Tensor<2>,
        features: Tensor<2>,
    ) -> Tensor<2> {
        let v = FourierEncoding::new(self.dir_freqs).encode(dirs);
        let mut inputs = vec![x.clone(), normals, v, features];
        if let Some(g) = self.grid_features(x) {
            inputs.push(g);
        }
        self.mlp.forward(Tensor::cat(inputs, 1))
    }

    /// The appearance grid's features at `x [N, 3]` (inside `[-1, 1]³`), `None` without one.
    pub fn grid_features(&self, x: Tensor<2>) -> Option<Tensor<2>> {
        self.grid
            .as_ref()
            .map(|grid| grid.forward(x.mul_scalar(0.5).add_scalar(0.5)))
    }

    /// Width of [`Self::grid_features`] (0 without a grid).
    pub fn d_grid(&self) -> usize {
        self.grid.as_ref().map_or(0, HashGrid::d_out)
    }

    /// As [`Self::forward`], with the SDF's features and the grid's given together
    /// (`[N, F + d_grid]`, as a stylizer blended them) instead of the grid's read at `x`.
    pub fn forward_blended(
        &self,
        x: Tensor<2>,
        normals: Tensor<2>,
        dirs: Tensor<2>,
        features_and_grid: Tensor<2>,
    ) -> Tensor<2> {
        let v = FourierEncoding::new(self.dir_freqs).encode(dirs);
        self.mlp
            .forward(Tensor::cat(vec![x, normals, v, features_and_grid], 1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn the_appearance_grid_widens_the_input_and_learns_from_the_colour() {
        let d = Device::flex().autodiff();
        d.seed(3);
        let grid = HashGridConfig::new()
            .with_log2_table(10)
            .with_base_resolution(4)
            .with_max_resolution(32);
        let plain = SurfaceColorConfig::new(5).init(&d);
        let color = SurfaceColorConfig::new(5).with_grid(Some(grid)).init(&d);
        let d_grid = color.grid.as_ref().unwrap().d_out();
        assert_eq!(
            color.mlp.hidden.layers[0].weight.dims()[0],
            plain.mlp.hidden.layers[0].weight.dims()[0] + d_grid
        );
        let n = 16;
        let x = Tensor::<2>::random([n, 3], Distribution::Uniform(-1.0, 1.0), &d);
        let rand3 = || Tensor::<2>::random([n, 3], Distribution::Default, &d);
        let rgb = color.forward(x, rand3(), rand3(), Tensor::<2>::zeros([n, 5], &d));
        assert_eq!(rgb.dims(), [n, 3]);
        let grads = rgb.sum().backward();
        let g = color.grid.as_ref().unwrap().table.val().grad(&grads);
        let g = g.expect("the grid's table has a gradient");
        assert!(g.abs().sum().into_scalar::<f32>() > 0.0);
    }

    #[test]
    fn the_grid_given_with_the_features_colours_as_the_grid_read_inside() {
        let d = Device::flex();
        d.seed(5);
        let grid = HashGridConfig::new()
            .with_log2_table(10)
            .with_base_resolution(4)
            .with_max_resolution(32);
        let color = SurfaceColorConfig::new(5).with_grid(Some(grid)).init(&d);
        let n = 8;
        let x = Tensor::<2>::random([n, 3], Distribution::Uniform(-1.0, 1.0), &d);
        let normals = Tensor::<2>::random([n, 3], Distribution::Default, &d);
        let dirs = Tensor::<2>::random([n, 3], Distribution::Default, &d);
        let f = Tensor::<2>::random([n, 5], Distribution::Default, &d);
        let inside = color.forward(x.clone(), normals.clone(), dirs.clone(), f.clone());
        let g = color.grid_features(x.clone()).unwrap();
        assert_eq!(g.dims()[1], color.d_grid());
        let given = color.forward_blended(x, normals, dirs, Tensor::cat(vec![f, g], 1));
        let diff = (inside - given).abs().max().into_scalar::<f32>();
        assert!(diff < 1e-6, "{diff}");
    }
}
