//! Burn's `x86-v4` feature picks AVX-512 GEMM kernels at run time; a CPU without AVX-512 must
//! get the same numbers from the fallback kernels. A CPU's features cannot be switched off from
//! inside a process, so this test forces the fallback by running the same computation under
//! QEMU's user-mode emulator with CPU models that lack AVX-512 (Haswell: AVX2 + FMA; Nehalem:
//! SSE only), and compares each run with the native one and with plain loops.
//!
//! The computation: odd-shaped matrix products, and 3×3 / 1×1 / strided convolutions with the
//! gradients of both their input and their weight, on flex, through Burn's conv2d and through
//! `ins-conv`'s op (f32 engine, with and without its fused ReLU: its BF16 engines are never
//! picked on these CPUs); the SIREN's `sin(ω·z)` op, the SDF networks' softplus and slope ops and
//! Adam's update, whose AVX-512 loops the emulated CPUs run 8 lanes wide (Haswell) or 4 (Nehalem),
//! bit for bit the same; the hash grid's lookup, Jacobian and both table gradients, whose
//! AVX-512 loops (16 points at a time) the emulated CPUs replace by the AVX2 ones (8, Haswell)
//! or the scalar ones (Nehalem), bit for bit the same; and the Gram-matrix op.
//!
//! A test binary without the libtest harness (`harness = false`): run with the environment
//! variable below, it is the child that computes and writes its numbers.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use burn::prelude::*;
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use ins_conv::Engine;
use ins_conv::op::ConvParams;
use ins_core::kernels::adam::kernel::{Step, update as adam_update};
use ins_core::kernels::gram::gram_flex;
use ins_core::kernels::hash_grid::GridShape;
use ins_core::kernels::hash_grid::kernel as grid;
use ins_core::kernels::sine::scaled_sin;
use ins_core::kernels::softplus::{softplus, softplus_slope};
use ins_tests::{max_rel_diff, values};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// Where the child writes its results (JSON).
const CHILD_OUT: &str = "INS_CPU_FALLBACK_OUT";

/// CPU models without AVX-512 that QEMU emulates, and the features each must (not) report.
const CPUS: &[(&str, &[&str], &[&str])] = &[
    ("Haswell", &["avx2", "fma"], &["avx512f"]),
    ("Nehalem", &["sse4.2"], &["avx", "avx512f"]),
];

/// Kernels agree to rounding: different kernels sum in different orders.
const TOLERANCE: f32 = 1e-4;
/// The element-wise kernels (sine, softplus, Adam), compiled once per vector width from one
/// loop, and the hash grid (16 points at a time with AVX-512, 8 with AVX2, else one) agree
/// exactly: the same arithmetic in the same order, whatever the width.
const ELEMENT_WISE: &[&str] = &["sine", "softplus", "adam", "hash_grid"];

type Results = BTreeMap<String, Vec<f32>>;

fn random(rng: &mut SmallRng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

fn tensor<const D: usize>(data: &[f32], shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::<1>::from_floats(data, device).reshape(shape)
}

/// Plain `[m, k] × [k, n]`.
fn naive_matmul(a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Vec<f32> {
    let mut c = vec![0.0f32; m * n];
    for i in 0..m {
        for j in 0..n {
            c[i * n + j] = (0..k).map(|p| a[i * k + p] * b[p * n + j]).sum();
        }
    }
    c
}

/// Plain convolution `[b, ci, h, w] * [co, ci, kh, kw]` with stride and zero padding.
fn naive_conv(
    x: &[f32],
    w: &[f32],
    [b, ci, h, wd]: [usize; 4],
    [co, kh, kw]: [usize; 3],
    stride: usize,
    pad: usize,
) -> Vec<f32> {
    let (oh, ow) = (
        (h + 2 * pad - kh) / stride + 1,
        (wd + 2 * pad - kw) / stride + 1,
    );
    let mut out = vec![0.0f32; b * co * oh * ow];
    for n in 0..b {
        for o in 0..co {
            for y in 0..oh {
                for xo in 0..ow {
                    let mut s = 0.0f32;
                    for c in 0..ci {
                        for dy in 0..kh {
                            for dx in 0..kw {
                                let iy = (y * stride + dy) as isize - pad as isize;
                                let ix = (xo * stride + dx) as isize - pad as isize;
                                if iy < 0 || ix < 0 || iy >= h as isize || ix >= wd as isize {
                                    continue;
                                }
                                s += x[((n * ci + c) * h + iy as usize) * wd + ix as usize]
                                    * w[((o * ci + c) * kh + dy) * kw + dx];
                            }
                        }
                    }
                    out[((n * co + o) * oh + y) * ow + xo] = s;
                }
            }
        }
    }
    out
}

/// Convolution cases: input `[b, ci, h, w]`, kernel `[co, kh, kw]`, stride, padding.
const CONVS: &[([usize; 4], [usize; 3], usize, usize)] = &[
    ([2, 5, 13, 11], [7, 3, 3], 1, 1),
    ([1, 48, 20, 17], [33, 3, 3], 1, 1),
    ([1, 19, 9, 14], [24, 1, 1], 1, 0),
    ([2, 6, 15, 12], [10, 3, 3], 2, 0),
];

/// Matrix products `[m, k] × [k, n]`.
const MATMULS: &[[usize; 3]] = &[[37, 129, 61], [67, 300, 129], [1, 17, 3]];

/// The computation every CPU model runs: same seeded inputs, flex, results by name.
fn compute() -> Results {
    let device = Device::flex().autodiff();
    let mut rng = SmallRng::seed_from_u64(20261123);
    let mut out = Results::new();
    for (i, &[m, k, n]) in MATMULS.iter().enumerate() {
        let (a, b) = (random(&mut rng, m * k), random(&mut rng, k * n));
        let c = tensor(&a, [m, k], &device).matmul(tensor(&b, [k, n], &device));
        out.insert(format!("matmul{i}"), values(c));
        out.insert(format!("matmul{i}_naive"), naive_matmul(&a, &b, m, k, n));
    }
    for (i, &(xs, [co, kh, kw], stride, pad)) in CONVS.iter().enumerate() {
        let x = random(&mut rng, xs.iter().product());
        let w = random(&mut rng, co * xs[1] * kh * kw);
        let xt = tensor(&x, xs, &device).require_grad();
        let wt = tensor(&w, [co, xs[1], kh, kw], &device).require_grad();
        let opts = ConvOptions::new([stride; 2], [pad; 2], [1, 1], 1);
        let y = conv2d(xt.clone(), wt.clone(), None, opts);
        let up = random(&mut rng, y.shape().num_elements());
        let up = tensor(&up, y.shape().dims::<4>(), &device);
        let grads = (y.clone() * up).sum().backward();
        out.insert(format!("conv{i}"), values(y));
        out.insert(
            format!("conv{i}_naive"),
            naive_conv(&x, &w, xs, [co, kh, kw], stride, pad),
        );
        out.insert(
            format!("conv{i}_grad_input"),
            values(xt.grad(&grads).expect("input gradient")),
        );
        out.insert(
            format!("conv{i}_grad_weight"),
            values(wt.grad(&grads).expect("weight gradient")),
        );
        for relu in [false, true] {
            let params = ConvParams {
                stride: [stride; 2],
                padding: [pad; 2],
                engine: Engine::F32,
                relu,
                reuse_kernel: false,
            };
            let y = ins_conv::conv2d(xt.clone(), wt.clone(), None, params);
            let up = random(&mut rng, y.shape().num_elements());
            let up = tensor(&up, y.shape().dims::<4>(), &device);
            let grads = (y.clone() * up).sum().backward();
            let name = format!("ins_conv{i}_relu{}", relu as u8);
            let mut naive = naive_conv(&x, &w, xs, [co, kh, kw], stride, pad);
            if relu {
                naive.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            out.insert(name.clone(), values(y));
            out.insert(format!("{name}_naive"), naive);
            let dx = xt.grad(&grads).expect("input gradient");
            out.insert(format!("{name}_grad_input"), values(dx));
            let dw = wt.grad(&grads).expect("weight gradient");
            out.insert(format!("{name}_grad_weight"), values(dw));
        }
    }
    let z = random(&mut rng, 4099);
    let zt = tensor(&z, [4099], &device).require_grad();
    let y = scaled_sin(zt.clone(), 30.0);
    let grads = y.clone().sum().backward();
    out.insert("sine".into(), values(y));
    out.insert(
        "sine_naive".into(),
        z.iter().map(|v| (30.0 * v).sin()).collect(),
    );
    out.insert(
        "sine_grad".into(),
        values(zt.grad(&grads).expect("sine gradient")),
    );
    // Softplus (β = 100) and its slope on [-0.1, 0.1], values and gradients.
    let u: Vec<f32> = z.iter().map(|v| v * 0.1).collect();
    let ut = tensor(&u, [4099], &device).require_grad();
    let sp = softplus(ut.clone(), 100.0);
    let slope = softplus_slope(ut.clone(), 100.0);
    let grads = (sp.clone() + slope.clone()).sum().backward();
    out.insert("softplus".into(), values(sp));
    out.insert(
        "softplus_naive".into(),
        u.iter()
            .map(|v| (100.0 * v).exp().ln_1p() / 100.0)
            .collect(),
    );
    out.insert("softplus_slope".into(), values(slope));
    out.insert(
        "softplus_slope_naive".into(),
        u.iter().map(|v| 1.0 / (1.0 + (-100.0 * v).exp())).collect(),
    );
    out.insert(
        "softplus_grad".into(),
        values(ut.grad(&grads).expect("softplus gradient")),
    );
    // One Adam step on 4099 parameters, in place, as the optimizer runs it.
    let step = Step {
        lr: 1e-3,
        beta_1: 0.9,
        beta_2: 0.999,
        scale: 0.3,
        epsilon: 1e-8,
    };
    let g = random(&mut rng, 4099);
    let mut param = random(&mut rng, 4099);
    let mut m = random(&mut rng, 4099);
    let mut v: Vec<f32> = random(&mut rng, 4099).iter().map(|x| x * x).collect();
    let (mut naive, mut naive_m, mut naive_v) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..4099 {
        let mi = 0.9 * m[i] + 0.1 * g[i];
        let vi = 0.999 * v[i] + 0.001 * g[i] * g[i];
        naive.push(param[i] - 1e-3 * 0.3 * mi / (vi.sqrt() + 1e-8));
        naive_m.push(mi);
        naive_v.push(vi);
    }
    adam_update(step, &g, &mut param, &mut m, &mut v);
    out.insert("adam".into(), param);
    out.insert("adam_naive".into(), naive);
    out.insert("adam_moments".into(), [m, v].concat());
    out.insert("adam_moments_naive".into(), [naive_m, naive_v].concat());
    hash_grid(&mut rng, &mut out);
    // The Gram matrix of a [1, 19, 130] feature map and its gradient.
    let (c, p) = (19, 130);
    let f = random(&mut rng, c * p);
    let ft = tensor(&f, [1, c, p], &device).require_grad();
    let g = gram_flex(ft.clone(), 1.0 / (c * p) as f32);
    let grads = (g.clone() * g.clone()).sum().backward();
    out.insert("gram".into(), values(g));
    let mut naive = naive_matmul(&f, &transpose(&f, c, p), c, p, c);
    naive.iter_mut().for_each(|v| *v /= (c * p) as f32);
    out.insert("gram_naive".into(), naive);
    out.insert(
        "gram_grad".into(),
        values(ft.grad(&grads).expect("Gram gradient")),
    );
    out
}

/// The hash grid's kernels on a grid with dense and hashed levels, at 16·40 + 5 points (some
/// outside the unit cube), and its lookup and Jacobian again one point at a time from the
/// corner weights.
fn hash_grid(rng: &mut SmallRng, out: &mut Results) {
    let layout = GridShape {
        levels: 5,
        features: 2,
        log2_table: 9,
        base_resolution: 3,
        max_resolution: 40,
    }
    .layout();
    let table = random(rng, layout.total_rows() * 2);
    let n = 16 * 40 + 5;
    let positions: Vec<f32> = random(rng, n * 3).iter().map(|v| v * 0.6 + 0.5).collect();
    let width = layout.levels() * 2;
    let mut encoded = vec![0f32; n * width];
    grid::forward(&layout, &table, &positions, &mut encoded);
    let mut naive = vec![0f32; n * width];
    for (i, p) in positions.chunks_exact(3).enumerate() {
        for l in 0..layout.levels() {
            let (rows, w) = layout.corner_weights(l, p);
            for f in 0..2 {
                naive[i * width + l * 2 + f] = (0..8).map(|c| w[c] * table[rows[c] * 2 + f]).sum();
            }
        }
    }
    let upstream = random(rng, n * width);
    let mut grad = vec![0f32; table.len()];
    grid::backward_table(&layout, &positions, &upstream, &mut grad);
    let mut jacobian = vec![0f32; n * width * 3];
    grid::jacobian(&layout, &table, &positions, &mut jacobian);
    let upstream = random(rng, n * width * 3);
    let mut jacobian_grad = vec![0f32; table.len()];
    grid::jacobian_backward_table(&layout, &positions, &upstream, &mut jacobian_grad);
    out.insert("hash_grid".into(), encoded);
    out.insert("hash_grid_naive".into(), naive);
    out.insert("hash_grid_table_grad".into(), grad);
    let mut naive_jacobian = vec![0f32; n * width * 3];
    for (i, p) in positions.chunks_exact(3).enumerate() {
        let p = [p[0], p[1], p[2]];
        for l in 0..layout.levels() {
            let (rows, _, dw) = layout.corners(l, p);
            for (e, v) in naive_jacobian[(i * width + l * 2) * 3..][..6]
                .iter_mut()
                .enumerate()
            {
                let (f, k) = (e / 3, e % 3);
                let inside = (0.0..=1.0).contains(&p[k]);
                *v = if inside {
                    (0..8).map(|c| dw[c][k] * table[rows[c] * 2 + f]).sum()
                } else {
                    0.0
                };
            }
        }
    }
    out.insert("hash_grid_jacobian".into(), jacobian);
    out.insert("hash_grid_jacobian_naive".into(), naive_jacobian);
    out.insert("hash_grid_jacobian_grad_table".into(), jacobian_grad);
}

/// `[rows, cols]` → `[cols, rows]`.
fn transpose(a: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    (0..cols * rows)
        .map(|i| a[(i % rows) * cols + i / rows])
        .collect()
}

fn features() -> BTreeMap<String, bool> {
    let mut f = BTreeMap::new();
    f.insert(
        "avx512f".into(),
        std::arch::is_x86_feature_detected!("avx512f"),
    );
    f.insert("avx2".into(), std::arch::is_x86_feature_detected!("avx2"));
    f.insert("avx".into(), std::arch::is_x86_feature_detected!("avx"));
    f.insert("fma".into(), std::arch::is_x86_feature_detected!("fma"));
    f.insert(
        "sse4.2".into(),
        std::arch::is_x86_feature_detected!("sse4.2"),
    );
    f
}

fn child(out: &Path) {
    let json = serde_json::json!({ "features": features(), "results": compute() });
    std::fs::write(out, serde_json::to_vec(&json).expect("json"))
        .unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}

fn read(path: &Path) -> (BTreeMap<String, bool>, Results) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: serde_json::Value = serde_json::from_str(&text).expect("child json");
    (
        serde_json::from_value(v["features"].clone()).expect("features"),
        serde_json::from_value(v["results"].clone()).expect("results"),
    )
}

/// Runs this binary as the child, under `qemu` with `cpu` when given.
fn run_child(dir: &Path, cpu: Option<&str>) -> (BTreeMap<String, bool>, Results) {
    let exe = std::env::current_exe().expect("test binary");
    let out = dir.join(format!("{}.json", cpu.unwrap_or("native")));
    let mut cmd = match cpu {
        Some(cpu) => {
            let mut c = Command::new("qemu-x86_64");
            c.args(["-cpu", cpu]).arg(&exe);
            c
        }
        None => Command::new(&exe),
    };
    let status = cmd.env(CHILD_OUT, &out).status().unwrap_or_else(|e| {
        panic!(
            "running {}: {e} (QEMU's user-mode emulator `qemu-x86_64` is needed: \
             scripts/setup.sh installs it)",
            cpu.map_or("the native child", |_| "qemu-x86_64")
        )
    });
    assert!(status.success(), "child on {cpu:?} failed: {status}");
    read(&out)
}

fn check_against_naive(label: &str, r: &Results) {
    for (name, v) in r
        .iter()
        .filter(|(n, _)| !n.ends_with("_naive") && !n.contains("grad"))
    {
        let naive = &r[&format!("{name}_naive")];
        let d = max_rel_diff(v, naive, 1e-3);
        assert!(
            d < TOLERANCE,
            "{label}: {name} differs from plain loops by {d}"
        );
    }
}

fn parent() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (native_features, native) = run_child(dir.path(), None);
    println!("native CPU: {native_features:?}");
    check_against_naive("native", &native);
    for (cpu, has, lacks) in CPUS {
        let (f, r) = run_child(dir.path(), Some(cpu));
        for feat in *has {
            assert!(f[*feat], "{cpu} under QEMU should report {feat}: {f:?}");
        }
        for feat in *lacks {
            assert!(
                !f[*feat],
                "{cpu} under QEMU should not report {feat}: {f:?}"
            );
        }
        check_against_naive(cpu, &r);
        assert_eq!(
            r.keys().collect::<Vec<_>>(),
            native.keys().collect::<Vec<_>>()
        );
        let mut worst = 0.0f32;
        for (name, v) in &r {
            if ELEMENT_WISE.iter().any(|k| name.starts_with(k)) && !name.ends_with("_naive") {
                let differ = v
                    .iter()
                    .zip(&native[name])
                    .filter(|(a, b)| a.to_bits() != b.to_bits());
                assert_eq!(
                    differ.count(),
                    0,
                    "{cpu}: {name} is not bit-identical to the native run"
                );
            }
            let d = max_rel_diff(v, &native[name], 1e-3);
            assert!(
                d < TOLERANCE,
                "{cpu}: {name} differs from the native run by {d}"
            );
            worst = worst.max(d);
        }
        println!(
            "{cpu} (no AVX-512): {} results agree with the native run, worst relative difference {worst:.2e}",
            r.len()
        );
    }
}

#[cfg(target_arch = "x86_64")]
fn main() {
    match std::env::var_os(CHILD_OUT) {
        Some(out) => child(Path::new(&out)),
        None => parent(),
    }
}

/// The fallback in question is x86's; elsewhere there is nothing to force.
#[cfg(not(target_arch = "x86_64"))]
fn main() {
    println!("cpu_fallback: x86_64 only, nothing to compare on this architecture");
}
