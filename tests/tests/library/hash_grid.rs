//! The hash-encoding kernel op equals the plain Burn-ops reference in value and in gradient
//! (table and positions) on flex and wgpu (the CubeCL kernels; Mesa's lavapipe where
//! there is no GPU), and the reference agrees with itself on every backend; the same for the
//! spatial Jacobian and its gradient.

use burn::prelude::*;
use ins_core::backend::BackendChoice;
use ins_core::kernels::hash_grid::{GridShape, op, reference};
use ins_tests::{max_rel_diff, values};

fn shape() -> GridShape {
    // Two dense levels and two hashed ones.
    GridShape {
        levels: 4,
        features: 2,
        log2_table: 8,
        base_resolution: 2,
        max_resolution: 16,
    }
}

fn inputs(device: &Device) -> (Tensor<2>, Tensor<2>, Tensor<2>, Tensor<3>) {
    let layout = shape().layout();
    let rows = layout.total_rows();
    let table: Vec<f32> = (0..rows * 2)
        .map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0)
        .collect();
    // Points inside, on the boundary and outside the unit cube (clamped).
    let mut pos = Vec::new();
    for i in 0..61 {
        let f = |k: usize| ((i * (7 + 3 * k) + 5 * k) % 97) as f32 / 96.0 * 1.1 - 0.05;
        pos.extend([f(0), f(1), f(2)]);
    }
    let n = pos.len() / 3;
    let up: Vec<f32> = (0..n * 8)
        .map(|i| ((i * 13 % 17) as f32 / 8.0) - 1.0)
        .collect();
    let upj: Vec<f32> = (0..n * 8 * 3)
        .map(|i| ((i * 11 % 19) as f32 / 9.0) - 1.0)
        .collect();
    (
        Tensor::<1>::from_floats(pos.as_slice(), device).reshape([n, 3]),
        Tensor::<1>::from_floats(table.as_slice(), device).reshape([rows, 2]),
        Tensor::<1>::from_floats(up.as_slice(), device).reshape([n, 8]),
        Tensor::<1>::from_floats(upj.as_slice(), device).reshape([n, 8, 3]),
    )
}

struct Result_ {
    encoding: Vec<f32>,
    grad_table: Vec<f32>,
    grad_positions: Vec<f32>,
    jacobian: Vec<f32>,
    jacobian_grad_table: Vec<f32>,
}

fn run(backend: BackendChoice, kernel: bool) -> Result_ {
    let device = backend.device().autodiff();
    let (p, t, up, upj) = inputs(&device);
    if kernel {
        assert!(
            op::kernel_device(&device),
            "{backend} should run the kernel"
        );
    }
    let p = p.require_grad();
    let t = t.require_grad();
    let enc = if kernel {
        op::encode_kernel(p.clone(), t.clone(), shape())
    } else {
        reference::encode(p.clone(), t.clone(), shape())
    };
    let grads = (enc.clone() * up).sum().backward();
    let grad_table = values(t.grad(&grads).expect("table gradient"));
    let grad_positions = values(p.grad(&grads).expect("position gradient"));
    let t2 = t.clone().detach().require_grad();
    let jac = if kernel {
        op::jacobian_kernel(p.clone().detach(), t2.clone(), shape())
    } else {
        reference::jacobian(p.clone().detach(), t2.clone(), shape())
    };
    let grads = (jac.clone() * upj).sum().backward();
    Result_ {
        encoding: values(enc),
        grad_table,
        grad_positions,
        jacobian: values(jac),
        jacobian_grad_table: values(t2.grad(&grads).expect("Jacobian table gradient")),
    }
}

fn assert_close(what: &str, a: &[f32], b: &[f32]) {
    let d = max_rel_diff(a, b, 1e-6);
    assert!(
        d < 1e-5,
        "{what}: differs by {d} relative to the largest entry"
    );
}

#[test]
fn kernel_op_equals_the_reference_in_value_and_gradient_on_every_backend() {
    let truth = run(BackendChoice::Flex, false);
    assert!(truth.grad_positions.iter().any(|v| *v != 0.0));
    let cases = [
        ("flex kernel", BackendChoice::Flex, true),
        ("wgpu reference", BackendChoice::Wgpu, false),
        ("wgpu kernel", BackendChoice::Wgpu, true),
    ];
    for (name, backend, kernel) in cases {
        // wgpu (lavapipe here) compiles its kernels on first use: a limit that fails the test.
        let r = ins_tests::within(ins_tests::WGPU_LIMIT_S, name, move || run(backend, kernel));
        assert_close(&format!("{name} encoding"), &r.encoding, &truth.encoding);
        assert_close(
            &format!("{name} table gradient"),
            &r.grad_table,
            &truth.grad_table,
        );
        assert_close(
            &format!("{name} position gradient"),
            &r.grad_positions,
            &truth.grad_positions,
        );
        assert_close(&format!("{name} Jacobian"), &r.jacobian, &truth.jacobian);
        assert_close(
            &format!("{name} Jacobian table gradient"),
            &r.jacobian_grad_table,
            &truth.jacobian_grad_table,
        );
    }
}

#[test]
fn reference_jacobian_matches_finite_differences_of_the_reference() {
    let device = Device::flex();
    let (p, t, _, _) = inputs(&device);
    let jac = values(reference::jacobian(p.clone(), t.clone(), shape()));
    let pv = values(p.clone());
    let n = pv.len() / 3;
    let eps = 1e-3;
    let mut worst = 0.0f32;
    for k in 0..3 {
        let shift = |s: f32| {
            let mut q = pv.clone();
            for i in 0..n {
                q[i * 3 + k] += s;
            }
            values(reference::encode(
                Tensor::<1>::from_floats(q.as_slice(), &device).reshape([n, 3]),
                t.clone(),
                shape(),
            ))
        };
        let (a, b) = (shift(eps), shift(-eps));
        for i in 0..n {
            // Skip points near a cell boundary or the cube's faces, where the encoding kinks.
            let near_kink = (0..4).any(|l| {
                let res = shape().layout().resolution[l] as f32;
                let x = pv[i * 3 + k] * res;
                (x - x.round()).abs() < 2.0 * eps * res
            }) || pv[i * 3 + k] < eps
                || pv[i * 3 + k] > 1.0 - eps;
            if near_kink {
                continue;
            }
            for e in 0..8 {
                let fd = (a[i * 8 + e] - b[i * 8 + e]) / (2.0 * eps);
                let j = jac[(i * 8 + e) * 3 + k];
                worst = worst.max((fd - j).abs() / (1.0 + j.abs()));
            }
        }
    }
    assert!(worst < 1e-2, "Jacobian vs finite differences: {worst}");
}
