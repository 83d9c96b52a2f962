//! A small MLP's layers as one kernel forward and three backward on the GPU backends, trained or
//! not: tiny-cuda-nn's fused MLPs, for the grid NeRF's density and colour networks and the
//! stylization's SIM and AM (every layer at most [`MAX_WIDTH`] wide).
//!
//! Why: layer by layer, a trained 64-wide layer is a product, a bias and a ReLU forward, and
//! backward two products, a mask and the bias's sums, each a Burn op with its host work and
//! most a launch of their own: on the CUDA stand-in, a grid NeRF step's two small MLPs took
//! 37 of its 100.5 launches (8 fused). Their sizes leave a GPU idle inside each kernel (a `[N, 64]`
//! activation is read and written in microseconds) and make the host's work per op the step's
//! floor. Here a unit takes a row through every layer, its activations in two arrays of its
//! own ([`cube`]'s forward keeps the hidden layers' outputs for the backward); backward, a unit
//! takes a row's gradient back through every layer (keeping each layer's pre-activation
//! gradient), a cube a block of rows sums every weight's and bias's gradient over its rows,
//! and a last kernel sums the blocks into each parameter's gradient.
//!
//! - [`cube`]: the kernels.
//! - [`op`]: a Burn op with that backward, under autodiff and Fusion.
//!
//! Flex keeps its own layers ([`super::dense_chain`]). `INS_FUSED_MLP=0` turns the fused
//! layers off (kept to weigh them against the layer-by-layer ops on a GPU).

pub mod cube;
pub mod op;

use burn::prelude::*;

use super::cube_f32;

/// The widest input or output a fused layer takes (a unit's activations are two arrays of it).
pub const MAX_WIDTH: usize = 64;
/// The most layers one op fuses (longer chains run as several).
pub const MAX_LAYERS: usize = 3;
/// Rows a cube sums the parameters' gradients over.
pub const ROWS_A_BLOCK: usize = 256;

/// The widths of a fused chain of two or three layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MlpShape {
    /// The input's width, then each layer's output width (0 past the last layer).
    pub widths: [usize; MAX_LAYERS + 1],
    /// Whether a ReLU follows each layer.
    pub relu: [bool; MAX_LAYERS],
}

impl MlpShape {
    /// Layers in the chain (2 or 3).
    pub fn layers(&self) -> usize {
        self.widths[1..].iter().take_while(|&&w| w > 0).count()
    }

    /// Layer `l`'s input width.
    pub fn input(&self, l: usize) -> usize {
        self.widths[l]
    }

    /// Layer `l`'s output width.
    pub fn output(&self, l: usize) -> usize {
        self.widths[l + 1]
    }

    /// The last layer's output width.
    pub fn out_width(&self) -> usize {
        self.output(self.layers() - 1)
    }

    /// The hidden layers' outputs a row keeps for the backward (every layer's but the last).
    pub fn hidden_width(&self) -> usize {
        (0..self.layers() - 1).map(|l| self.output(l)).sum()
    }

    /// Every layer's pre-activation gradient a row keeps for the parameters' sums.
    pub fn pre_width(&self) -> usize {
        (0..self.layers()).map(|l| self.output(l)).sum()
    }

    /// Where layer `l`'s outputs start in a row of the hidden outputs or of the
    /// pre-activation gradients.
    pub fn column(&self, l: usize) -> usize {
        (0..l).map(|k| self.output(k)).sum()
    }

    /// Where layer `l`'s parameters start in the summed gradient: each layer's weights `[I, O]`
    /// (row-major), then its bias `[O]`.
    pub fn param_offset(&self, l: usize) -> usize {
        (0..l).map(|k| (self.input(k) + 1) * self.output(k)).sum()
    }

    /// The parameters' count, every layer's weights and bias.
    pub fn params(&self) -> usize {
        self.param_offset(self.layers())
    }
}

/// The shapes of the weight and bias gradients `[w0, b0, w1, b1, w2, b2]` (`[1, 1]` and `[1]`
/// past the last layer).
pub fn param_shapes(shape: MlpShape) -> [Vec<usize>; 2 * MAX_LAYERS] {
    std::array::from_fn(|k| {
        let l = k / 2;
        let (i, o) = match l < shape.layers() {
            true => (shape.input(l), shape.output(l)),
            false => (1, 1),
        };
        if k % 2 == 0 { vec![i, o] } else { vec![o] }
    })
}

/// Blocks of [`ROWS_A_BLOCK`] rows the parameters' gradients are summed over (one for none).
pub fn row_blocks(rows: usize) -> usize {
    rows.div_ceil(ROWS_A_BLOCK).max(1)
}

/// Whether chains are fused off a CPU: unless `INS_FUSED_MLP=0` (`ins-cli bench` reports
/// which ran, `fused_mlp`).
pub fn asked() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ON.get_or_init(|| std::env::var("INS_FUSED_MLP").as_deref() != Ok("0"))
}

/// `x [N, I]` through `layers` (weights `[I, O]`, biases `[O]`, a ReLU after or not) fused, in
/// pieces of up to [`MAX_LAYERS`]: Some where it applies (a CubeCL device, every tensor f32,
/// at least two layers, every width at most [`MAX_WIDTH`], [`asked`]), else None.
pub fn fused_chain(x: &Tensor<2>, layers: &[(Tensor<2>, Tensor<1>, bool)]) -> Option<Tensor<2>> {
    let mut dtypes = vec![x.dtype()];
    dtypes.extend(layers.iter().flat_map(|(w, b, _)| [w.dtype(), b.dtype()]));
    let fits = layers.len() >= 2
        && x.dims()[1] <= MAX_WIDTH
        && layers.iter().all(|(w, _, _)| w.dims()[1] <= MAX_WIDTH);
    if !fits || !asked() || !cube_f32(&x.device(), &dtypes) {
        return None;
    }
    // Pieces of three, the last two of four or five kept as a pair (a piece is two or three).
    let mut pieces = Vec::new();
    let mut rest = layers;
    while !rest.is_empty() {
        let take = match rest.len() {
            4 => 2,
            n => n.min(MAX_LAYERS),
        };
        pieces.push(&rest[..take]);
        rest = &rest[take..];
    }
    Some(pieces.into_iter().fold(x.clone(), op::fused_mlp))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shape_places_each_layers_columns_and_parameters() {
        let s = MlpShape {
            widths: [31, 64, 64, 3],
            relu: [true, true, false],
        };
        assert_eq!(s.layers(), 3);
        assert_eq!(s.out_width(), 3);
        assert_eq!(s.hidden_width(), 128);
        assert_eq!(s.pre_width(), 131);
        assert_eq!([s.column(0), s.column(1), s.column(2)], [0, 64, 128]);
        assert_eq!(s.param_offset(1), 32 * 64);
        assert_eq!(s.param_offset(2), 32 * 64 + 65 * 64);
        assert_eq!(s.params(), 32 * 64 + 65 * 64 + 65 * 3);
        let two = MlpShape {
            widths: [32, 64, 16, 0],
            relu: [true, false, false],
        };
        assert_eq!(
            (two.layers(), two.out_width(), two.hidden_width()),
            (2, 16, 64)
        );
        assert_eq!(row_blocks(0), 1);
        assert_eq!(row_blocks(257), 2);
    }
}
