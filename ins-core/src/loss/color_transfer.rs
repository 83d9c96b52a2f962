//! ARF's colour transfer: an affine map of RGB that gives a set of photos the mean and the
//! covariance of a painting's colours, `c ↦ A·c + b` with `A = Σ_s^½ Σ_c^−½` and
//! `b = μ_s − A·μ_c`. Stylization then keeps the photos' content in the painting's palette: the
//! content term compares renders with recoloured photos, so it no longer pulls the colours back
//! to the scene's, and the style term is left the strokes.

/// An affine colour map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorTransfer {
    /// Row-major 3×3 matrix.
    pub matrix: [[f32; 3]; 3],
    /// Offset.
    pub offset: [f32; 3],
}

/// Mean and covariance of RGB triples.
fn moments(colors: &[[f32; 3]]) -> ([f64; 3], [[f64; 3]; 3]) {
    let n = colors.len().max(1) as f64;
    let mut mean = [0.0f64; 3];
    for c in colors {
        for k in 0..3 {
            mean[k] += c[k] as f64 / n;
        }
    }
    let mut cov = [[0.0f64; 3]; 3];
    for c in colors {
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += (c[i] as f64 - mean[i]) * (c[j] as f64 - mean[j]) / n;
            }
        }
    }
    (mean, cov)
}

/// Eigenvalues and eigenvectors (columns of the returned matrix) of a symmetric 3×3 matrix,
/// by cyclic Jacobi rotations.
#[allow(clippy::needless_range_loop)] // matrix indices read as the algebra does
fn symmetric_eigen(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..64 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off < 1e-15 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for k in 0..3 {
                let (vkp, vkq) = (v[k][p], v[k][q]);
                v[k][p] = c * vkp - s * vkq;
                v[k][q] = s * vkp + c * vkq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

/// `V · diag(f(λ)) · Vᵀ` of a symmetric matrix: a function of it (square root, inverse square
/// root), eigenvalues floored at `floor` so a flat set of colours stays finite.
#[allow(clippy::needless_range_loop)]
fn matrix_function(m: [[f64; 3]; 3], floor: f64, f: impl Fn(f64) -> f64) -> [[f64; 3]; 3] {
    let (lambda, v) = symmetric_eigen(m);
    let d = lambda.map(|l| f(l.max(floor)));
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = (0..3).map(|k| v[i][k] * d[k] * v[j][k]).sum();
        }
    }
    out
}

fn matmul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

impl ColorTransfer {
    /// The map that gives `content` colours the mean and covariance of `style` colours.
    pub fn fit(content: &[[f32; 3]], style: &[[f32; 3]]) -> Self {
        const FLOOR: f64 = 1e-5;
        let (mc, cc) = moments(content);
        let (ms, cs) = moments(style);
        let a = matmul(
            matrix_function(cs, FLOOR, f64::sqrt),
            matrix_function(cc, FLOOR, |l| 1.0 / l.sqrt()),
        );
        let offset =
            std::array::from_fn(|i| (ms[i] - (0..3).map(|k| a[i][k] * mc[k]).sum::<f64>()) as f32);
        Self {
            matrix: a.map(|row| row.map(|v| v as f32)),
            offset,
        }
    }

    /// `A·c + b`, clamped to [0, 1].
    pub fn apply(&self, c: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|i| {
            (self.offset[i] + (0..3).map(|k| self.matrix[i][k] * c[k]).sum::<f32>()).clamp(0.0, 1.0)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 33) as f32) / (1u64 << 31) as f32
    }

    #[test]
    fn recoloured_photos_take_the_paintings_mean_and_covariance() {
        let mut s = 7u64;
        // Photos: warm, correlated colours; painting: cool, different spread.
        let content: Vec<[f32; 3]> = (0..4000)
            .map(|_| {
                let t = lcg(&mut s);
                [
                    0.5 + 0.3 * t,
                    0.4 + 0.2 * t + 0.05 * lcg(&mut s),
                    0.2 + 0.1 * lcg(&mut s),
                ]
            })
            .collect();
        let style: Vec<[f32; 3]> = (0..4000)
            .map(|_| {
                let u = lcg(&mut s);
                [
                    0.1 + 0.1 * lcg(&mut s),
                    0.2 + 0.2 * u,
                    0.5 + 0.3 * u + 0.1 * lcg(&mut s),
                ]
            })
            .collect();
        let ct = ColorTransfer::fit(&content, &style);
        let mapped: Vec<[f32; 3]> = content.iter().map(|&c| ct.apply(c)).collect();
        let (m1, c1) = moments(&mapped);
        let (m2, c2) = moments(&style);
        for i in 0..3 {
            assert!((m1[i] - m2[i]).abs() < 2e-3, "mean {i}: {m1:?} vs {m2:?}");
            for j in 0..3 {
                assert!(
                    (c1[i][j] - c2[i][j]).abs() < 2e-4,
                    "cov {i}{j}: {c1:?} vs {c2:?}"
                );
            }
        }
    }

    #[test]
    fn jacobi_diagonalises_a_symmetric_matrix() {
        let m = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 1.0]];
        let (l, v) = symmetric_eigen(m);
        for k in 0..3 {
            for i in 0..3 {
                let mv: f64 = (0..3).map(|j| m[i][j] * v[j][k]).sum();
                assert!((mv - l[k] * v[i][k]).abs() < 1e-9);
            }
        }
        let root = matrix_function(m, 0.0, f64::sqrt);
        let back = matmul(root, root);
        for i in 0..3 {
            for j in 0..3 {
                assert!((back[i][j] - m[i][j]).abs() < 1e-9);
            }
        }
    }
}
