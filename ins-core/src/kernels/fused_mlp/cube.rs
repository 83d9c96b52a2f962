//! [`super`]'s kernels: a unit a row forward (its activations in two arrays of
//! [`MAX_WIDTH`]) and backward (its gradient back through every layer), and a cube a block of
//! rows for the parameters' sums. Widths are compile-time: each chain's shape compiles once.
//!
//! Inputs: `x [N, I]`, the layers' weights `[I, O]` (row-major) and biases `[O]`; the forward
//! keeps `hidden [N, H]` (the layers' outputs but the last's, side by side), the backward
//! writes `grad_pre [N, G]` (every layer's pre-activation gradient, side by side).

use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::{MAX_WIDTH, MlpShape, ROWS_A_BLOCK, row_blocks};
use crate::kernels::cube_launch::{contiguous_f32, empty_like, grid};

/// `out[o] = b[o] + Σ_i input[i]·w[i·O + o]` for `o < O`, through a ReLU if `relu`.
#[cube]
fn layer_forward(
    w: &[f32],
    b: &[f32],
    input: &Array<f32>,
    out: &mut Array<f32>,
    #[comptime] i_width: usize,
    #[comptime] o_width: usize,
    #[comptime] relu: bool,
) {
    for o in 0..o_width {
        let mut acc = b[o];
        for i in 0..i_width {
            acc += input[i] * w[i * o_width + o];
        }
        if relu {
            acc = f32::max(acc, 0.0);
        }
        out[o] = acc;
    }
}

/// `values[0..width]` into `to[at..at + width]`.
#[cube]
fn store(values: &Array<f32>, to: &mut [f32], at: usize, #[comptime] width: usize) {
    for k in 0..width {
        to[at + k] = values[k];
    }
}

/// This unit's row `r` of `rows [N, width]` (the units past the last row stop), with two
/// activation arrays, the first holding the row.
#[cube]
fn row_unit(rows: &[f32], #[comptime] width: usize) -> (usize, Array<f32>, Array<f32>) {
    if ABSOLUTE_POS >= rows.len() / width {
        terminate!();
    }
    let r = ABSOLUTE_POS;
    let mut a = Array::<f32>::new(MAX_WIDTH);
    for k in 0..width {
        a[k] = rows[r * width + k];
    }
    (r, a, Array::<f32>::new(MAX_WIDTH))
}

/// Row `r` of `x` through every layer: the last's output in `y`, the others' in `hidden`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn mlp_forward_kernel(
    x: &[f32],
    w0: &[f32],
    b0: &[f32],
    w1: &[f32],
    b1: &[f32],
    w2: &[f32],
    b2: &[f32],
    y: &mut [f32],
    hidden: &mut [f32],
    #[comptime] widths: MlpWidths,
) {
    let (r, mut a, mut b) = row_unit(x, widths.i0);
    layer_forward(w0, b0, &a, &mut b, widths.i0, widths.o0, widths.relu0);
    store(&b, hidden, r * widths.hidden, widths.o0);
    layer_forward(w1, b1, &b, &mut a, widths.o0, widths.o1, widths.relu1);
    if comptime!(widths.o2 > 0) {
        store(&a, hidden, r * widths.hidden + widths.o0, widths.o1);
        layer_forward(w2, b2, &a, &mut b, widths.o1, widths.o2, widths.relu2);
        store(&b, y, r * widths.o2, widths.o2);
    } else {
        store(&a, y, r * widths.o1, widths.o1);
    }
}

/// One layer backward for a row: `g[0..O]`, the gradient at the layer's output (whose values
/// are `outs[out_at..]`), becomes its pre-activation gradient (zero where the ReLU was),
/// written to `grad_pre[pre_at..]`; `into[0..I]` gets the gradient at the layer's input.
#[cube]
#[allow(clippy::too_many_arguments)]
fn layer_backward(
    w: &[f32],
    outs: &[f32],
    out_at: usize,
    g: &mut Array<f32>,
    into: &mut Array<f32>,
    grad_pre: &mut [f32],
    pre_at: usize,
    #[comptime] i_width: usize,
    #[comptime] o_width: usize,
    #[comptime] relu: bool,
) {
    for o in 0..o_width {
        let mut v = g[o];
        // Two ifs: `relu` is known when the kernel compiles, the output only when it runs.
        #[allow(clippy::collapsible_if)]
        if relu {
            if outs[out_at + o] <= 0.0 {
                v = 0.0;
            }
        }
        g[o] = v;
        grad_pre[pre_at + o] = v;
    }
    for i in 0..i_width {
        let mut acc = 0.0f32;
        for o in 0..o_width {
            acc += w[i * o_width + o] * g[o];
        }
        into[i] = acc;
    }
}

/// Row `r`'s gradient `grad[r]` back through every layer: `grad_x[r]` and `grad_pre[r]`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn mlp_backward_kernel(
    hidden: &[f32],
    y: &[f32],
    w0: &[f32],
    w1: &[f32],
    w2: &[f32],
    grad: &[f32],
    grad_x: &mut [f32],
    grad_pre: &mut [f32],
    #[comptime] widths: MlpWidths,
) {
    let (r, mut a, mut b) = row_unit(grad, widths.last);
    if comptime!(widths.o2 > 0) {
        let w2_at = r * widths.pre + widths.o0 + widths.o1;
        layer_backward(
            w2,
            y,
            r * widths.o2,
            &mut a,
            &mut b,
            grad_pre,
            w2_at,
            widths.o1,
            widths.o2,
            widths.relu2,
        );
        let w1_at = r * widths.pre + widths.o0;
        layer_backward(
            w1,
            hidden,
            r * widths.hidden + widths.o0,
            &mut b,
            &mut a,
            grad_pre,
            w1_at,
            widths.o0,
            widths.o1,
            widths.relu1,
        );
    } else {
        let w1_at = r * widths.pre + widths.o0;
        layer_backward(
            w1,
            y,
            r * widths.o1,
            &mut a,
            &mut b,
            grad_pre,
            w1_at,
            widths.o0,
            widths.o1,
            widths.relu1,
        );
        for k in 0..widths.o0 {
            a[k] = b[k];
        }
    }
    layer_backward(
        w0,
        hidden,
        r * widths.hidden,
        &mut a,
        &mut b,
        grad_pre,
        r * widths.pre,
        widths.i0,
        widths.o0,
        widths.relu0,
    );
    store(&b, grad_x, r * widths.i0, widths.i0);
}

/// One layer's share of a block's parameter sums: entry `e` of its `(I + 1)·O` (weights, then
/// the bias as a row of ones) is `Σ_rows input[row, i]·grad_pre[row, o]`, written to
/// `partials[out_at + e]`; the cube's units take the entries in turn.
#[cube]
#[allow(clippy::too_many_arguments)]
fn layer_partials(
    input: &[f32],
    grad_pre: &[f32],
    partials: &mut [f32],
    rows_from: usize,
    rows_to: usize,
    out_at: usize,
    #[comptime] in_stride: usize,
    #[comptime] in_at: usize,
    #[comptime] pre_stride: usize,
    #[comptime] pre_at: usize,
    #[comptime] i_width: usize,
    #[comptime] o_width: usize,
) {
    let entries = comptime!((i_width + 1) * o_width);
    let mut e = UNIT_POS as usize;
    while e < entries {
        let i = e / o_width;
        let o = e % o_width;
        let mut acc = 0.0f32;
        if i < i_width {
            for r in rows_from..rows_to {
                acc += input[r * in_stride + in_at + i] * grad_pre[r * pre_stride + pre_at + o];
            }
        } else {
            for r in rows_from..rows_to {
                acc += grad_pre[r * pre_stride + pre_at + o];
            }
        }
        partials[out_at + e] = acc;
        e += CUBE_DIM as usize;
    }
}

/// Cube `(block, layer)`: the layer's parameter sums over the block's rows, into row `block`
/// of `partials [blocks, P]`.
#[cube(launch)]
fn mlp_partials_kernel(
    x: &[f32],
    hidden: &[f32],
    grad_pre: &[f32],
    partials: &mut [f32],
    #[comptime] widths: MlpWidths,
) {
    let i0 = widths.i0;
    let o0 = widths.o0;
    let o1 = widths.o1;
    let o2 = widths.o2;
    let h = widths.hidden;
    let p = widths.pre;
    let params = widths.params;
    let n = x.len() / i0;
    let block = CUBE_POS_X as usize;
    let from = block * ROWS_A_BLOCK;
    let to = usize::min(from + ROWS_A_BLOCK, n);
    let row = block * params;
    let layer = CUBE_POS_Y;
    let s0 = comptime!((i0 + 1) * o0);
    let s1 = comptime!((o0 + 1) * o1);
    if layer == 0 {
        layer_partials(
            x, grad_pre, partials, from, to, row, i0, 0usize, p, 0usize, i0, o0,
        );
    } else if layer == 1 {
        layer_partials(
            hidden,
            grad_pre,
            partials,
            from,
            to,
            row + s0,
            h,
            0usize,
            p,
            o0,
            o0,
            o1,
        );
    } else if comptime!(o2 > 0) {
        let at = row + s0 + s1;
        layer_partials(
            hidden,
            grad_pre,
            partials,
            from,
            to,
            at,
            h,
            o0,
            p,
            o0 + o1,
            o1,
            o2,
        );
    }
}

/// Entry `e` of the parameters' gradient: `partials`' column `e` summed over the blocks,
/// written to its layer's weights or bias.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn mlp_sum_kernel(
    partials: &[f32],
    w0: &mut [f32],
    b0: &mut [f32],
    w1: &mut [f32],
    b1: &mut [f32],
    w2: &mut [f32],
    b2: &mut [f32],
    #[comptime] widths: MlpWidths,
) {
    let params = widths.params;
    if ABSOLUTE_POS >= params {
        terminate!();
    }
    let e = ABSOLUTE_POS;
    let blocks = partials.len() / params;
    let mut acc = 0.0f32;
    for block in 0..blocks {
        acc += partials[block * params + e];
    }
    let i0 = widths.i0;
    let o0 = widths.o0;
    let o1 = widths.o1;
    let s0 = comptime!((i0 + 1) * o0);
    let s1 = comptime!((o0 + 1) * o1);
    if e < s0 {
        write_entry(w0, b0, e, acc, comptime!(i0 * o0));
    } else if e < s0 + s1 {
        write_entry(w1, b1, e - s0, acc, comptime!(o0 * o1));
    } else {
        write_entry(w2, b2, e - s0 - s1, acc, comptime!(o1 * widths.o2));
    }
}

/// A layer's entry `e` (its weights, then its bias) set to `value`.
#[cube]
fn write_entry(w: &mut [f32], b: &mut [f32], e: usize, value: f32, #[comptime] weights: usize) {
    if e < weights {
        w[e] = value;
    } else {
        b[e - weights] = value;
    }
}

/// A chain's shape as the kernels take it at compile time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MlpWidths {
    i0: usize,
    o0: usize,
    o1: usize,
    /// 0 for a chain of two.
    o2: usize,
    last: usize,
    hidden: usize,
    pre: usize,
    params: usize,
    relu0: bool,
    relu1: bool,
    relu2: bool,
}

impl From<MlpShape> for MlpWidths {
    fn from(s: MlpShape) -> Self {
        Self {
            i0: s.widths[0],
            o0: s.widths[1],
            o1: s.widths[2],
            o2: s.widths[3],
            last: s.out_width(),
            hidden: s.hidden_width(),
            pre: s.pre_width(),
            params: s.params(),
            relu0: s.relu[0],
            relu1: s.relu[1],
            relu2: s.relu[2],
        }
    }
}

/// Contiguous f32 inputs, checked.
fn inputs<const K: usize>(tensors: [CubeTensor; K], names: [&str; K]) -> [CubeTensor; K] {
    contiguous_f32("the fused MLP", tensors, names)
}

/// `(y [N, O_last], hidden [N, H])`: [`mlp_forward_kernel`] over `x [N, I]` and
/// `[w0, b0, w1, b1, w2, b2]`.
pub fn forward(
    x: CubeTensor,
    params: [CubeTensor; 6],
    shape: MlpShape,
) -> (CubeTensor, CubeTensor) {
    let n = x.meta.shape()[0];
    let y = empty_like(&x, [n, shape.out_width()]);
    let hidden = empty_like(&x, [n, shape.hidden_width()]);
    if n == 0 {
        return (y, hidden);
    }
    let (client, (count, dim)) = (x.client.clone(), grid(&x, n));
    let [x] = inputs([x], ["input"]);
    let [w0, b0, w1, b1, w2, b2] = inputs(params, ["w0", "b0", "w1", "b1", "w2", "b2"]);
    mlp_forward_kernel::launch(
        &client,
        count,
        dim,
        x.into_buffer_arg(),
        w0.into_buffer_arg(),
        b0.into_buffer_arg(),
        w1.into_buffer_arg(),
        b1.into_buffer_arg(),
        w2.into_buffer_arg(),
        b2.into_buffer_arg(),
        y.clone().into_buffer_arg(),
        hidden.clone().into_buffer_arg(),
        MlpWidths::from(shape),
    );
    (y, hidden)
}

/// `(grad_x [N, I], grad_pre [N, G])`: [`mlp_backward_kernel`] for the upstream `grad [N, O_last]`.
pub fn backward(
    hidden: CubeTensor,
    y: CubeTensor,
    weights: [CubeTensor; 3],
    grad: CubeTensor,
    shape: MlpShape,
) -> (CubeTensor, CubeTensor) {
    let n = grad.meta.shape()[0];
    let grad_x = empty_like(&grad, [n, shape.input(0)]);
    let grad_pre = empty_like(&grad, [n, shape.pre_width()]);
    if n == 0 {
        return (grad_x, grad_pre);
    }
    let (client, (count, dim)) = (grad.client.clone(), grid(&grad, n));
    let [hidden, y, grad] = inputs([hidden, y, grad], ["hidden", "output", "upstream gradient"]);
    let [w0, w1, w2] = inputs(weights, ["w0", "w1", "w2"]);
    mlp_backward_kernel::launch(
        &client,
        count,
        dim,
        hidden.into_buffer_arg(),
        y.into_buffer_arg(),
        w0.into_buffer_arg(),
        w1.into_buffer_arg(),
        w2.into_buffer_arg(),
        grad.into_buffer_arg(),
        grad_x.clone().into_buffer_arg(),
        grad_pre.clone().into_buffer_arg(),
        MlpWidths::from(shape),
    );
    (grad_x, grad_pre)
}

/// Units a cube of [`mlp_partials_kernel`] (each takes every 256th entry of a layer's).
const UNITS: u32 = 256;

/// Every layer's weight and bias gradients, `[w0, b0, w1, b1, w2, b2]` (a chain of two: the
/// last two `[1, 1]` and `[1]`, unwritten): [`mlp_partials_kernel`]'s sums a block of
/// [`ROWS_A_BLOCK`] rows, then [`mlp_sum_kernel`]'s over the blocks.
pub fn param_grads(
    x: CubeTensor,
    hidden: CubeTensor,
    grad_pre: CubeTensor,
    shape: MlpShape,
) -> [CubeTensor; 6] {
    let n = x.meta.shape()[0];
    let blocks = row_blocks(n);
    let partials = empty_like(&x, [blocks, shape.params()]);
    let client = x.client.clone();
    let outs = super::param_shapes(shape).map(|dims| empty_like(&x, dims));
    let [x, hidden, grad_pre] = inputs(
        [x, hidden, grad_pre],
        ["input", "hidden", "pre-activation gradient"],
    );
    mlp_partials_kernel::launch(
        &client,
        CubeCount::Static(blocks as u32, shape.layers() as u32, 1),
        CubeDim::new_1d(UNITS),
        x.into_buffer_arg(),
        hidden.into_buffer_arg(),
        grad_pre.into_buffer_arg(),
        partials.clone().into_buffer_arg(),
        MlpWidths::from(shape),
    );
    let (count, dim) = grid(&partials, shape.params());
    let [w0, b0, w1, b1, w2, b2] = outs.clone().map(|t| t.into_buffer_arg());
    mlp_sum_kernel::launch(
        &client,
        count,
        dim,
        partials.into_buffer_arg(),
        w0,
        b0,
        w1,
        b1,
        w2,
        b2,
        MlpWidths::from(shape),
    );
    outs
}
