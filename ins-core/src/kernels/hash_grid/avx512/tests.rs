//! The vector loops against the scalar arithmetic, bit for bit.

use super::super::kernel::{GridShape, backward_table, forward, jacobian, jacobian_backward_table};
use super::*;

/// Dense and hashed levels; 16·62 + 7 points (a ragged tail), some outside the unit cube
/// and some on cell boundaries.
fn case() -> (Layout, Vec<f32>, Vec<f32>) {
    let layout = GridShape {
        levels: 6,
        features: 2,
        log2_table: 10,
        base_resolution: 3,
        max_resolution: 97,
    }
    .layout();
    assert!(layout.dense.contains(&true) && layout.dense.contains(&false));
    let mut s = 0x9e37_79b9_u32;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s as f32 / u32::MAX as f32
    };
    let table = (0..layout.total_rows() * 2)
        .map(|_| next() * 2.0 - 1.0)
        .collect();
    // Past two of the transposes' 1024-point chunks, and a partial vector of 16.
    let mut positions: Vec<f32> = (0..(16 * 130 + 7) * 3)
        .map(|_| next() * 1.2 - 0.1)
        .collect();
    positions[..9].copy_from_slice(&[0.0, 0.5, 1.0, 1.0 / 3.0, 0.25, 0.75, 1.0, 0.0, 0.0]);
    (layout, table, positions)
}

#[test]
fn sixteen_points_at_a_time_give_the_scalar_loops_bits() {
    let (layout, table, positions) = case();
    let n = positions.len() / 3;
    let width = layout.levels() * 2;
    let mut out = vec![0f32; n * width];
    forward(&layout, &table, &positions, &mut out);
    let grad_out: Vec<f32> = (0..n * width)
        .map(|i| {
            if i % 11 == 0 {
                0.0
            } else {
                ((i * 7) % 13) as f32 / 6.0 - 1.0
            }
        })
        .collect();
    let mut grad = vec![0f32; table.len()];
    backward_table(&layout, &positions, &grad_out, &mut grad);
    // The scalar arithmetic, one point after another.
    let mut want_grad = vec![0f32; table.len()];
    for (i, p) in positions.chunks_exact(3).enumerate() {
        for l in 0..layout.levels() {
            let (rows, w) = layout.corner_weights(l, p);
            let (mut a, mut b) = (0f32, 0f32);
            let go = &grad_out[i * width + 2 * l..i * width + 2 * l + 2];
            for c in 0..8 {
                a += w[c] * table[rows[c] * 2];
                b += w[c] * table[rows[c] * 2 + 1];
                if go != [0.0, 0.0] {
                    want_grad[rows[c] * 2] += w[c] * go[0];
                    want_grad[rows[c] * 2 + 1] += w[c] * go[1];
                }
            }
            let got = &out[i * width + 2 * l..i * width + 2 * l + 2];
            assert_eq!(
                got[0].to_bits(),
                a.to_bits(),
                "point {i}, level {l}: {got:?} vs {a}"
            );
            assert_eq!(
                got[1].to_bits(),
                b.to_bits(),
                "point {i}, level {l}: {got:?} vs {b}"
            );
        }
    }
    for (k, (g, w)) in grad.iter().zip(&want_grad).enumerate() {
        assert_eq!(g.to_bits(), w.to_bits(), "table gradient {k}: {g} vs {w}");
    }
    if cpu_has_avx512f() {
        // The vector loops ran (the tail of 7 by the scalar ones).
        let columns = columns(&positions);
        let mut dst = vec![0f32; 2 * n];
        assert_eq!(
            encode_level(&layout, 3, &table, &columns, &mut dst),
            16 * 130
        );
    }
}

#[test]
fn the_jacobian_sixteen_points_at_a_time_gives_the_scalar_loops_bits() {
    let (layout, table, positions) = case();
    let n = positions.len() / 3;
    let width = layout.levels() * 6;
    let mut jac = vec![0f32; n * width];
    jacobian(&layout, &table, &positions, &mut jac);
    let grad_jac: Vec<f32> = (0..n * width)
        .map(|i| ((i * 5) % 17) as f32 / 8.0 - 1.0)
        .collect();
    let mut grad = vec![0f32; table.len()];
    jacobian_backward_table(&layout, &positions, &grad_jac, &mut grad);
    // The scalar arithmetic, one point after another.
    let mut want_grad = vec![0f32; table.len()];
    for (i, p) in positions.chunks_exact(3).enumerate() {
        let p = [p[0], p[1], p[2]];
        let inside = p.map(|v| if (0.0..=1.0).contains(&v) { 1.0 } else { 0.0 });
        for l in 0..layout.levels() {
            let (rows, _, dw) = layout.corners(l, p);
            let mut want = [0f32; 6];
            for c in 0..8 {
                for fi in 0..2 {
                    let mut t = -0.0f32;
                    for k in 0..3 {
                        want[fi * 3 + k] += dw[c][k] * table[rows[c] * 2 + fi];
                        t += dw[c][k] * inside[k] * grad_jac[i * width + l * 6 + fi * 3 + k];
                    }
                    want_grad[rows[c] * 2 + fi] += t;
                }
            }
            for (e, w) in want.iter().enumerate() {
                let w = if inside[e % 3] == 1.0 { *w } else { 0.0 };
                let got = jac[i * width + l * 6 + e];
                assert_eq!(
                    got.to_bits(),
                    w.to_bits(),
                    "point {i}, level {l}, entry {e}: {got} vs {w}"
                );
            }
        }
    }
    for (k, (g, w)) in grad.iter().zip(&want_grad).enumerate() {
        assert_eq!(g.to_bits(), w.to_bits(), "table gradient {k}: {g} vs {w}");
    }
    if cpu_has_avx512f() {
        let columns = columns(&positions);
        let mut rows = vec![0f32; n * width];
        assert_eq!(
            jacobian_points(&layout, &table, &columns, &mut rows),
            16 * 130
        );
    }
}
