//! The vector loops against the scalar arithmetic, bit for bit: through `kernel`'s entry points
//! (whichever loops this CPU runs, a ragged tail left to the scalar ones) and each vector path
//! this CPU has, called directly (so an AVX-512 machine checks the AVX2 loops too).

use super::super::kernel::{
    GridShape, Layout, backward_table, forward, jacobian, jacobian_backward_table,
};
use super::{PATHS, columns};

/// Dense and hashed levels; 16·130 + 7 points (a ragged tail), some outside the unit cube
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

/// An upstream gradient of the encoding (`n·L·2`), some points' zero.
fn grad_out(n: usize, width: usize) -> Vec<f32> {
    (0..n * width)
        .map(|i| {
            if i % 11 == 0 {
                0.0
            } else {
                ((i * 7) % 13) as f32 / 6.0 - 1.0
            }
        })
        .collect()
}

/// An upstream gradient of the Jacobian (`n·L·6`).
fn grad_jac(n: usize, width: usize) -> Vec<f32> {
    (0..n * width)
        .map(|i| ((i * 5) % 17) as f32 / 8.0 - 1.0)
        .collect()
}

/// The encoding (`n·L·2`) and its table gradient, one point after another.
fn scalar_encoding(
    layout: &Layout,
    table: &[f32],
    positions: &[f32],
    grad_out: &[f32],
) -> (Vec<f32>, Vec<f32>) {
    let width = layout.levels() * 2;
    let mut out = vec![0f32; positions.len() / 3 * width];
    let mut grad = vec![0f32; table.len()];
    for (i, p) in positions.chunks_exact(3).enumerate() {
        for l in 0..layout.levels() {
            let (rows, w) = layout.corner_weights(l, p);
            let (mut a, mut b) = (0f32, 0f32);
            let go = &grad_out[i * width + 2 * l..i * width + 2 * l + 2];
            for c in 0..8 {
                a += w[c] * table[rows[c] * 2];
                b += w[c] * table[rows[c] * 2 + 1];
                if go != [0.0, 0.0] {
                    grad[rows[c] * 2] += w[c] * go[0];
                    grad[rows[c] * 2 + 1] += w[c] * go[1];
                }
            }
            out[i * width + 2 * l] = a;
            out[i * width + 2 * l + 1] = b;
        }
    }
    (out, grad)
}

/// The Jacobian (`n·L·6`, before clamped axes are zeroed when `zero_clamped` is false) and its
/// table gradient, one point after another.
fn scalar_jacobian(
    layout: &Layout,
    table: &[f32],
    positions: &[f32],
    grad_jac: &[f32],
    zero_clamped: bool,
) -> (Vec<f32>, Vec<f32>) {
    let width = layout.levels() * 6;
    let mut jac = vec![0f32; positions.len() / 3 * width];
    let mut grad = vec![0f32; table.len()];
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
                    grad[rows[c] * 2 + fi] += t;
                }
            }
            for (e, w) in want.iter().enumerate() {
                let keep = !zero_clamped || inside[e % 3] == 1.0;
                jac[i * width + l * 6 + e] = if keep { *w } else { 0.0 };
            }
        }
    }
    (jac, grad)
}

fn same_bits(what: &str, got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert_eq!(g.to_bits(), w.to_bits(), "{what} {k}: {g} vs {w}");
    }
}

#[test]
fn the_encoding_and_its_table_gradient_give_the_scalar_loops_bits() {
    let (layout, table, positions) = case();
    let n = positions.len() / 3;
    let width = layout.levels() * 2;
    let go = grad_out(n, width);
    let mut out = vec![0f32; n * width];
    forward(&layout, &table, &positions, &mut out);
    let mut grad = vec![0f32; table.len()];
    backward_table(&layout, &positions, &go, &mut grad);
    let (want_out, want_grad) = scalar_encoding(&layout, &table, &positions, &go);
    same_bits("encoding", &out, &want_out);
    same_bits("table gradient", &grad, &want_grad);
}

#[test]
fn the_jacobian_and_its_table_gradient_give_the_scalar_loops_bits() {
    let (layout, table, positions) = case();
    let n = positions.len() / 3;
    let width = layout.levels() * 6;
    let gj = grad_jac(n, width);
    let mut jac = vec![0f32; n * width];
    jacobian(&layout, &table, &positions, &mut jac);
    let mut grad = vec![0f32; table.len()];
    jacobian_backward_table(&layout, &positions, &gj, &mut grad);
    let (want_jac, want_grad) = scalar_jacobian(&layout, &table, &positions, &gj, true);
    same_bits("Jacobian", &jac, &want_jac);
    same_bits("table gradient", &grad, &want_grad);
}

/// Each vector path this CPU has, called directly on every level: the points it takes (all
/// but the ragged tail) get the scalar loops' bits.
#[test]
fn every_vector_path_this_cpu_has_gives_the_scalar_loops_bits() {
    let (layout, table, positions) = case();
    let levels = layout.levels();
    let mut ran = 0;
    for path in PATHS.iter().filter(|p| (p.usable)(2)) {
        ran += 1;
        let name = path.name;
        let m = positions.len() / 3 / path.lanes * path.lanes;
        let taken = &positions[..3 * m];
        let cols = columns(taken);
        let (go, gj) = (grad_out(m, levels * 2), grad_jac(m, levels * 6));
        let (want_out, want_grad) = scalar_encoding(&layout, &table, taken, &go);
        let (want_jac, want_jgrad) = scalar_jacobian(&layout, &table, taken, &gj, false);
        let mut grad = vec![0f32; table.len()];
        let mut jgrad = vec![0f32; table.len()];
        for l in 0..levels {
            let mut dst = vec![0f32; 2 * m];
            assert_eq!(
                (path.encode_level)(&layout, l, &table, &cols, &mut dst),
                m,
                "{name}"
            );
            let want: Vec<f32> = (0..m)
                .flat_map(|i| {
                    [
                        want_out[i * levels * 2 + 2 * l],
                        want_out[i * levels * 2 + 2 * l + 1],
                    ]
                })
                .collect();
            same_bits(&format!("{name} encoding, level {l}"), &dst, &want);
            let level_go: Vec<f32> = (0..m)
                .flat_map(|i| [go[i * levels * 2 + 2 * l], go[i * levels * 2 + 2 * l + 1]])
                .collect();
            let rows = layout.offset[l]..layout.offset[l] + layout.rows[l];
            let g = &mut grad[2 * rows.start..2 * rows.end];
            assert_eq!(
                (path.scatter_level)(&layout, l, &cols, &level_go, g),
                m,
                "{name}"
            );
            let g = &mut jgrad[2 * rows.start..2 * rows.end];
            assert_eq!(
                (path.jacobian_scatter_level)(&layout, l, &cols, &gj, g),
                m,
                "{name}"
            );
        }
        same_bits(&format!("{name} table gradient"), &grad, &want_grad);
        same_bits(
            &format!("{name} Jacobian's table gradient"),
            &jgrad,
            &want_jgrad,
        );
        let mut jac = vec![0f32; m * levels * 6];
        assert_eq!(
            (path.jacobian_points)(&layout, &table, &cols, &mut jac),
            m,
            "{name}"
        );
        same_bits(&format!("{name} Jacobian"), &jac, &want_jac);
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        assert!(ran > 0, "a CPU with AVX2 ran no vector path");
    }
    let _ = ran;
}
