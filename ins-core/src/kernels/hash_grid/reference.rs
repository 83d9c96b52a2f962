//! The hash encoding from ordinary Burn tensor ops: the plain reference the kernel op is held
//! to, and the path backends without the kernel (wgpu) train with. Same conventions as
//! [`super::kernel`]; differentiable in the table and the positions by Burn's own autodiff.

use burn::prelude::*;

use super::kernel::{GridShape, Layout};

/// Large primes of the spatial hash (instant-ngp).
const PRIMES: [u64; 3] = [1, 2_654_435_761, 805_459_861];

/// The corners of every point in level `l`: rows `[N]` and weights `[N]` per corner, and the
/// per-axis weight derivatives `[N, 3]` per corner.
fn level_corners(
    layout: &Layout,
    l: usize,
    positions: &Tensor<2>,
) -> Vec<(Tensor<1, Int>, Tensor<1>, Tensor<2>)> {
    let n = layout.resolution[l];
    let nf = n as f32;
    let x = positions.clone().clamp(0.0, 1.0).mul_scalar(nf);
    // The cell index carries no gradient; the fraction carries all of it.
    let cell = x.clone().detach().floor().clamp_max((n - 1) as f32);
    let frac = x - cell.clone();
    let cell = cell.int();
    let [count, _] = positions.dims();
    let axis =
        |t: &Tensor<2, Int>, k: usize| t.clone().slice([0..count, k..k + 1]).reshape([count]);
    let fax = |k: usize| frac.clone().slice([0..count, k..k + 1]).reshape([count]);
    let mask = (layout.rows[l] - 1) as i64;
    let verts = (n + 1) as i64;
    (0..8)
        .map(|c| {
            let b = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let coords: Vec<Tensor<1, Int>> = (0..3)
                .map(|k| axis(&cell, k).add_scalar(b[k] as i64))
                .collect();
            let local = if layout.dense[l] {
                coords[0].clone()
                    + coords[1].clone().mul_scalar(verts)
                    + coords[2].clone().mul_scalar(verts * verts)
            } else {
                // (v·P) mod 2^k only needs P mod 2^k, which keeps every product below 2^31.
                let term = |k: usize| {
                    coords[k]
                        .clone()
                        .mul_scalar((PRIMES[k] as i64) & mask)
                        .bitwise_and_scalar(mask)
                };
                term(0).bitwise_xor(term(1)).bitwise_xor(term(2))
            };
            let rows = local.add_scalar(layout.offset[l] as i64);
            let t: Vec<Tensor<1>> = (0..3)
                .map(|k| {
                    if b[k] == 1 {
                        fax(k)
                    } else {
                        fax(k).neg().add_scalar(1.0)
                    }
                })
                .collect();
            let s = |k: usize| if b[k] == 1 { nf } else { -nf };
            let w = t[0].clone() * t[1].clone() * t[2].clone();
            let dw = Tensor::stack(
                vec![
                    (t[1].clone() * t[2].clone()).mul_scalar(s(0)),
                    (t[0].clone() * t[2].clone()).mul_scalar(s(1)),
                    (t[0].clone() * t[1].clone()).mul_scalar(s(2)),
                ],
                1,
            );
            (rows, w, dw)
        })
        .collect()
}

/// `positions [N, 3]` in `[0, 1]`, `table [R, F]` → `[N, L·F]`.
pub fn encode(positions: Tensor<2>, table: Tensor<2>, shape: GridShape) -> Tensor<2> {
    let layout = shape.layout();
    let levels = (0..layout.levels())
        .map(|l| {
            level_corners(&layout, l, &positions)
                .into_iter()
                .map(|(rows, w, _)| table.clone().select(0, rows) * w.unsqueeze_dim(1))
                .reduce(|a, b| a + b)
                .expect("eight corners")
        })
        .collect();
    Tensor::cat(levels, 1)
}

/// The spatial Jacobian `[N, L·F, 3]` (zero along axes where the position is clamped).
pub fn jacobian(positions: Tensor<2>, table: Tensor<2>, shape: GridShape) -> Tensor<3> {
    let layout = shape.layout();
    let inside = positions
        .clone()
        .greater_equal_elem(0.0)
        .bool_and(positions.clone().lower_equal_elem(1.0))
        .float()
        .unsqueeze_dim::<3>(1);
    let levels = (0..layout.levels())
        .map(|l| {
            level_corners(&layout, l, &positions)
                .into_iter()
                .map(|(rows, _, dw)| {
                    // [N, F, 1] · [N, 1, 3]
                    table.clone().select(0, rows).unsqueeze_dim::<3>(2) * dw.unsqueeze_dim(1)
                })
                .reduce(|a, b| a + b)
                .expect("eight corners")
        })
        .collect();
    Tensor::cat(levels, 1) * inside
}
