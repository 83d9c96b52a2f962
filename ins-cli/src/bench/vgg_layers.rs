//! `ins-cli bench vgg-layers`: where a `vgg` step's time goes, per convolution: the forward
//! (convolution + ReLU), the gradient to its input, and the gradient to its weights (which a
//! frozen VGG never needs; timed to show what skipping it saves), at the asked precision (the
//! weight gradient is f32 in both).

use std::time::Instant;

use anyhow::Result;
use burn::prelude::*;
use burn::tensor::activation::relu;
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Distribution, FloatDType};
use ins_conv::op::ConvParams;
use ins_conv::{Engine, Precision};
use vgg_import::onnx::VGG16_CHANNELS;

/// Input side of each convolution for a 256×256 image (pools after conv 2, 4 and 7).
const SIDES: [usize; 10] = [256, 256, 128, 128, 64, 64, 64, 32, 32, 32];
const NAMES: [&str; 10] = [
    "conv1_1", "conv1_2", "conv2_1", "conv2_2", "conv3_1", "conv3_2", "conv3_3", "conv4_1",
    "conv4_2", "conv4_3",
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median milliseconds of `f` over `steps` runs after one warm-up.
fn time(steps: usize, mut f: impl FnMut()) -> f64 {
    f();
    median(
        (0..steps.max(1))
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    )
}

/// Prints one JSON line per convolution of VGG-16 at 256×256 (batch 1) on `device` (an
/// autodiff device): forward, input-gradient and weight-gradient milliseconds and GFLOP/s.
pub fn run(device: &Device, backend: &str, steps: usize, precision: Precision) -> Result<()> {
    let opts = ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
    let precision = precision.effective_on(device);
    // conv + ReLU as VGG runs it at this precision: Burn's conv2d in f32 (or f16 on a GPU), the
    // fused op in bf16.
    let conv_relu = |x: Tensor<4>, w: Tensor<4>, b: Tensor<1>| match precision {
        Precision::F32 => relu(conv2d(x, w, Some(b), opts.clone())),
        Precision::F16 => {
            let half = FloatDType::F16;
            let y = conv2d(x.cast(half), w.cast(half), Some(b.cast(half)), opts.clone());
            relu(y).cast(FloatDType::F32)
        }
        Precision::Bf16 => {
            let params = ConvParams {
                stride: [1, 1],
                padding: [1, 1],
                engine: Engine::bf16_or_f32(),
                relu: true,
                reuse_kernel: true,
            };
            ins_conv::conv2d(x, w, Some(b), params)
        }
    };
    let mut totals = [0.0f64; 3];
    for (i, (&side, name)) in SIDES.iter().zip(NAMES).enumerate() {
        let c_in = if i == 0 { 3 } else { VGG16_CHANNELS[i - 1] };
        let c_out = VGG16_CHANNELS[i];
        let x = Tensor::<4>::random([1, c_in, side, side], Distribution::Default, device);
        let w = Tensor::<4>::random([c_out, c_in, 3, 3], Distribution::Default, device);
        let b = Tensor::<1>::random([c_out], Distribution::Default, device);
        let up = Tensor::<4>::random([1, c_out, side, side], Distribution::Default, device);
        let fwd = time(steps, || {
            let y = conv_relu(x.clone(), w.clone(), b.clone());
            let _ = y.sum().into_scalar::<f32>();
        });
        // Backward of (y · up).sum() with only one of x, w tracked; the forward is subtracted.
        let with_backward = |track_x: bool| {
            time(steps, || {
                let (xx, ww) = if track_x {
                    (x.clone().require_grad(), w.clone())
                } else {
                    (x.clone(), w.clone().require_grad())
                };
                let y = conv_relu(xx.clone(), ww.clone(), b.clone());
                let grads = (y * up.clone()).sum().backward();
                let g = if track_x {
                    xx.grad(&grads)
                } else {
                    ww.grad(&grads)
                };
                let _ = g.map(|g| g.sum().into_scalar::<f32>());
            })
        };
        let input_grad = (with_backward(true) - fwd).max(0.0);
        let weight_grad = (with_backward(false) - fwd).max(0.0);
        let gflop = 2.0 * (c_in * 9 * c_out * side * side) as f64 / 1e9;
        totals[0] += fwd;
        totals[1] += input_grad;
        totals[2] += weight_grad;
        println!(
            "{}",
            serde_json::json!({
                "workload": "vgg-layers", "backend": backend, "precision": precision.to_string(), "layer": name,
                "input": [c_in, side, side], "out_channels": c_out, "gflop": (gflop * 100.0).round() / 100.0,
                "forward_ms": (fwd * 10.0).round() / 10.0,
                "input_grad_ms": (input_grad * 10.0).round() / 10.0,
                "weight_grad_ms": (weight_grad * 10.0).round() / 10.0,
                "forward_gflops": (gflop / fwd * 1e3 * 10.0).round() / 10.0,
            })
        );
    }
    println!(
        "{}",
        serde_json::json!({
            "workload": "vgg-layers", "backend": backend, "precision": precision.to_string(), "layer": "total",
            "forward_ms": (totals[0] * 10.0).round() / 10.0,
            "input_grad_ms": (totals[1] * 10.0).round() / 10.0,
            "weight_grad_ms": (totals[2] * 10.0).round() / 10.0,
        })
    );
    Ok(())
}
