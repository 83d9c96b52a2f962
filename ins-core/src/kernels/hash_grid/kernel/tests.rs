//! The hash encoding's maths against exact values and finite differences.

use super::*;

fn shape() -> GridShape {
    GridShape {
        levels: 4,
        features: 2,
        log2_table: 8,
        base_resolution: 2,
        max_resolution: 16,
    }
}

fn table(layout: &Layout, seed: u32) -> Vec<f32> {
    (0..layout.total_rows() * layout.features)
        .map(|i| (((i as u32).wrapping_mul(2_654_435_761) ^ seed) % 1000) as f32 / 500.0 - 1.0)
        .collect()
}

#[test]
fn layout_grows_geometrically_and_hashes_fine_levels() {
    let l = shape().layout();
    assert_eq!(l.resolution, [2, 4, 8, 16]);
    assert_eq!(l.dense, [true, true, false, false]);
    assert_eq!(l.rows, [27, 125, 256, 256]);
    assert_eq!(l.offset, [0, 27, 152, 408]);
    assert_eq!(l.total_rows(), 664);
}

#[test]
fn fast_corner_rows_agree_with_the_reference_hash() {
    let layout = shape().layout();
    for p in points().chunks_exact(3) {
        for l in 0..4 {
            let (rows, w) = layout.corner_weights(l, p);
            let (rows2, w2, _) = layout.corners(l, [p[0], p[1], p[2]]);
            assert_eq!(rows, rows2);
            for c in 0..8 {
                assert!((w[c] - w2[c]).abs() < 1e-6);
            }
        }
    }
}

#[test]
fn interpolation_is_exact_at_vertices_and_linear_between() {
    let layout = shape().layout();
    let t = table(&layout, 1);
    let mut out = vec![0.0; 8];
    // At a vertex of every level (the origin), the encoding is the vertex's vector.
    forward(&layout, &t, &[0.0, 0.0, 0.0], &mut out);
    for l in 0..4 {
        let r = layout.row(l, 0, 0, 0);
        assert_eq!(&out[l * 2..l * 2 + 2], &t[r * 2..r * 2 + 2]);
    }
    // Midway along x in level 0 (resolution 2): the mean of two vertices.
    forward(&layout, &t, &[0.25, 0.0, 0.0], &mut out);
    let (a, b) = (layout.row(0, 0, 0, 0), layout.row(0, 1, 0, 0));
    for f in 0..2 {
        let want = 0.5 * (t[a * 2 + f] + t[b * 2 + f]);
        assert!((out[f] - want).abs() < 1e-6);
    }
}

/// Points away from every level's cell boundaries (finite differences cross no kink).
fn points() -> Vec<f32> {
    vec![
        0.13, 0.71, 0.42, 0.9, 0.05, 0.33, 0.47, 0.53, 0.77, 0.011, 0.99, 0.6,
    ]
}

#[test]
fn gradients_match_finite_differences() {
    let layout = shape().layout();
    let t = table(&layout, 2);
    let p = points();
    let n = p.len() / 3;
    let width = 8;
    // A fixed linear functional of the output.
    let g: Vec<f32> = (0..n * width).map(|i| ((i * 7) % 5) as f32 - 2.0).collect();
    let loss = |t: &[f32], p: &[f32]| {
        let mut out = vec![0.0; n * width];
        forward(&layout, t, p, &mut out);
        out.iter().zip(&g).map(|(a, b)| (a * b) as f64).sum::<f64>()
    };
    let mut gt = vec![0.0; t.len()];
    backward_table(&layout, &p, &g, &mut gt);
    let eps = 1e-2;
    for i in (0..t.len()).step_by(7) {
        let mut tp = t.clone();
        tp[i] += eps;
        let mut tm = t.clone();
        tm[i] -= eps;
        let fd = (loss(&tp, &p) - loss(&tm, &p)) / (2.0 * eps as f64);
        assert!(
            (fd as f32 - gt[i]).abs() < 1e-3,
            "table {i}: {fd} vs {}",
            gt[i]
        );
    }
    let mut gp = vec![0.0; p.len()];
    backward_positions(&layout, &t, &p, &g, &mut gp);
    let eps = 1e-4;
    for i in 0..p.len() {
        let mut pp = p.clone();
        pp[i] += eps;
        let mut pm = p.clone();
        pm[i] -= eps;
        let fd = (loss(&t, &pp) - loss(&t, &pm)) / (2.0 * eps as f64);
        assert!(
            (fd as f32 - gp[i]).abs() < 2e-2 * (1.0 + fd.abs() as f32),
            "position {i}: {fd} vs {}",
            gp[i]
        );
    }
}

#[test]
fn jacobian_matches_finite_differences_and_its_backward_is_its_transpose() {
    let layout = shape().layout();
    let t = table(&layout, 3);
    let p = points();
    let n = p.len() / 3;
    let mut jac = vec![0.0; n * 8 * 3];
    jacobian(&layout, &t, &p, &mut jac);
    let eps = 1e-4;
    for i in 0..n {
        for k in 0..3 {
            let mut pp = p.clone();
            pp[i * 3 + k] += eps;
            let mut pm = p.clone();
            pm[i * 3 + k] -= eps;
            let (mut a, mut b) = (vec![0.0; n * 8], vec![0.0; n * 8]);
            forward(&layout, &t, &pp, &mut a);
            forward(&layout, &t, &pm, &mut b);
            for e in 0..8 {
                let fd = (a[i * 8 + e] - b[i * 8 + e]) / (2.0 * eps);
                let j = jac[(i * 8 + e) * 3 + k];
                assert!(
                    (fd - j).abs() < 2e-2 * (1.0 + j.abs()),
                    "point {i} axis {k}: {fd} vs {j}"
                );
            }
        }
    }
    // The Jacobian is linear in the table: its backward is the adjoint.
    let gj: Vec<f32> = (0..jac.len()).map(|i| ((i * 3) % 7) as f32 - 3.0).collect();
    let mut gt = vec![0.0; t.len()];
    jacobian_backward_table(&layout, &p, &gj, &mut gt);
    let dt: Vec<f32> = (0..t.len())
        .map(|i| ((i * 5) % 11) as f32 / 11.0 - 0.5)
        .collect();
    let mut jd = vec![0.0; jac.len()];
    jacobian(&layout, &dt, &p, &mut jd);
    let lhs: f64 = jd.iter().zip(&gj).map(|(a, b)| (a * b) as f64).sum();
    let rhs: f64 = gt.iter().zip(&dt).map(|(a, b)| (a * b) as f64).sum();
    assert!(
        (lhs - rhs).abs() < 1e-3 * (1.0 + lhs.abs()),
        "{lhs} vs {rhs}"
    );
}
