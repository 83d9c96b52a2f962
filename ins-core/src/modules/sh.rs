//! Real spherical harmonics up to degree 3 (16 coefficients) of unit directions: the view
//! encoding of instant-ngp's colour network.

use burn::prelude::*;

/// `dirs [N, 3]` (unit) → `[N, 16]`, bands 0–3 in the usual (Sloan) order and normalization.
pub fn spherical_harmonics(dirs: Tensor<2>) -> Tensor<2> {
    let [n, _] = dirs.dims();
    let c = |k: usize| dirs.clone().slice([0..n, k..k + 1]);
    let (x, y, z) = (c(0), c(1), c(2));
    let (xx, yy, zz) = (
        x.clone() * x.clone(),
        y.clone() * y.clone(),
        z.clone() * z.clone(),
    );
    let (xy, yz, xz) = (
        x.clone() * y.clone(),
        y.clone() * z.clone(),
        x.clone() * z.clone(),
    );
    let ones = Tensor::<2>::ones([n, 1], &dirs.device());
    let terms = vec![
        ones.mul_scalar(0.282_094_79),
        y.clone().mul_scalar(-0.488_602_51),
        z.clone().mul_scalar(0.488_602_51),
        x.clone().mul_scalar(-0.488_602_51),
        xy.clone().mul_scalar(1.092_548_4),
        yz.clone().mul_scalar(-1.092_548_4),
        (zz.clone().mul_scalar(3.0).sub_scalar(1.0)).mul_scalar(0.315_391_57),
        xz.clone().mul_scalar(-1.092_548_4),
        (xx.clone() - yy.clone()).mul_scalar(0.546_274_2),
        (y.clone() * (xx.clone().mul_scalar(3.0) - yy.clone())).mul_scalar(-0.590_043_6),
        (xy.clone() * z.clone()).mul_scalar(2.890_611_4),
        (y.clone() * (zz.clone().mul_scalar(5.0).sub_scalar(1.0))).mul_scalar(-0.457_045_8),
        (z.clone() * (zz.clone().mul_scalar(5.0).sub_scalar(3.0))).mul_scalar(0.373_176_33),
        (x.clone() * (zz.clone().mul_scalar(5.0).sub_scalar(1.0))).mul_scalar(-0.457_045_8),
        (z.clone() * (xx.clone() - yy.clone())).mul_scalar(1.445_305_7),
        (x * (xx - yy.mul_scalar(3.0))).mul_scalar(-0.590_043_6),
    ];
    Tensor::cat(terms, 1)
}

/// The same 16 values for one unit direction, on the host.
pub fn spherical_harmonics_host(d: [f32; 3]) -> [f32; 16] {
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    [
        0.282_094_79,
        -0.488_602_51 * y,
        0.488_602_51 * z,
        -0.488_602_51 * x,
        1.092_548_4 * xy,
        -1.092_548_4 * yz,
        0.315_391_57 * (3.0 * zz - 1.0),
        -1.092_548_4 * xz,
        0.546_274_2 * (xx - yy),
        -0.590_043_6 * y * (3.0 * xx - yy),
        2.890_611_4 * xy * z,
        -0.457_045_8 * y * (5.0 * zz - 1.0),
        0.373_176_33 * z * (5.0 * zz - 3.0),
        -0.457_045_8 * x * (5.0 * zz - 1.0),
        1.445_305_7 * z * (xx - yy),
        -0.590_043_6 * x * (xx - 3.0 * yy),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_and_tensor_versions_agree() {
        let d = Device::flex();
        let v = [0.36f32, -0.48, 0.8];
        let t = spherical_harmonics(Tensor::<2>::from_floats([v], &d))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        for (a, b) in t.iter().zip(spherical_harmonics_host(v)) {
            assert!((a - b).abs() < 1e-6);
        }
    }

    #[test]
    fn harmonics_are_orthonormal_on_the_sphere() {
        // Monte-Carlo over a Fibonacci sphere: ∫ Y_i Y_j dΩ = δ_ij.
        let d = Device::flex();
        let n = 20000;
        let mut v = Vec::with_capacity(n * 3);
        let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f32;
            v.extend([r * a.cos(), r * a.sin(), z]);
        }
        let y = spherical_harmonics(Tensor::<1>::from_floats(v.as_slice(), &d).reshape([n, 3]));
        let gram = y
            .clone()
            .transpose()
            .matmul(y)
            .mul_scalar(4.0 * std::f32::consts::PI / n as f32);
        let g = gram.into_data().try_to_vec::<f32>().unwrap();
        for i in 0..16 {
            for j in 0..16 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (g[i * 16 + j] - want).abs() < 2e-3,
                    "({i}, {j}): {}",
                    g[i * 16 + j]
                );
            }
        }
    }
}
