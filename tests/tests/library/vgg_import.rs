//! The ONNX importer against onnxruntime's activations (fixtures written by
//! scripts/make_vgg_fixture.py), and its errors.

use burn::prelude::*;
use ins_tests::{fixture, max_rel_diff, npy_tensor4, read_npy, real_vgg, values};
use vgg_import::onnx::{InputLayout, read_vgg_like_onnx, read_vgg_onnx};
use vgg_import::{Preprocess, Vgg, Vgg16Features, VggError};

fn check_layers(vgg: &Vgg, input: &str, prefix: &str, device: &Device) {
    let x = npy_tensor4(&fixture(&format!("vgg/{input}")), device);
    let f = vgg.features(x);
    for (name, t) in vgg_import::VggFeatures::NAMES.iter().zip(f.style_layers()) {
        let (shape, expected) = read_npy(&fixture(&format!("vgg/{prefix}_{name}.npy")));
        assert_eq!(t.dims().to_vec(), shape, "{prefix} {name} shape");
        let got = values(t.clone());
        let d = max_rel_diff(&got, &expected, 1e-3);
        assert!(d < 1e-4, "{prefix} {name}: max relative difference {d}");
    }
}

#[test]
fn tf2onnx_layout_matches_onnxruntime() {
    let device = Device::flex();
    let w = read_vgg_like_onnx(&fixture("vgg/tiny_nhwc.onnx"), None).unwrap();
    assert_eq!(w.layout, InputLayout::Nhwc);
    assert_eq!(w.detected, Preprocess::Caffe);
    let vgg = Vgg {
        net: Vgg16Features::from_weights(&w, &device),
        preprocess: w.detected,
    };
    check_layers(&vgg, "input.npy", "tiny_nhwc", &device);
}

#[test]
fn torchvision_layout_matches_onnxruntime() {
    let device = Device::flex();
    let w = read_vgg_like_onnx(&fixture("vgg/tiny_nchw.onnx"), None).unwrap();
    assert_eq!(w.layout, InputLayout::Nchw);
    assert_eq!(w.detected, Preprocess::Torch);
    let vgg = Vgg {
        net: Vgg16Features::from_weights(&w, &device),
        preprocess: w.detected,
    };
    check_layers(&vgg, "input.npy", "tiny_nchw", &device);
}

#[test]
fn real_vgg16_matches_onnxruntime() {
    let device = Device::flex();
    let vgg = real_vgg(&device);
    assert_eq!(vgg.preprocess, Preprocess::Caffe);
    check_layers(&vgg, "real_input.npy", "real", &device);
    // A second load comes from the converted cache and gives the same network.
    let again = real_vgg(&device);
    let a = values(vgg.net.convs[9].weight.val());
    let b = values(again.net.convs[9].weight.val());
    assert_eq!(a, b);
}

#[test]
fn missing_file_is_a_clear_error() {
    let e = read_vgg_onnx(std::path::Path::new("/nonexistent/vgg.onnx"))
        .err()
        .unwrap();
    assert!(matches!(e, VggError::Missing { .. }));
    let msg = e.to_string();
    assert!(
        msg.contains("/nonexistent/vgg.onnx") && msg.contains("vgg fetch"),
        "{msg}"
    );
}

#[test]
fn not_onnx_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("garbage.onnx");
    std::fs::write(&p, b"this is not a protobuf \xff\xfe\x00 at all").unwrap();
    let e = read_vgg_onnx(&p).err().unwrap();
    assert!(matches!(e, VggError::NotOnnx { .. }), "{e}");
    assert!(e.to_string().contains("garbage.onnx"));
}

#[test]
fn too_few_convolutions_is_a_clear_error() {
    // Read without the VGG-16 widths so that the count, not the first width, is what fails.
    let p = fixture("vgg/too_few.onnx");
    let e = read_vgg_like_onnx(&p, None).err().unwrap();
    match &e {
        VggError::TooFewConvolutions { found, .. } => assert_eq!(*found, 6),
        other => panic!("unexpected {other}"),
    }
    assert!(e.to_string().contains("too_few.onnx"));
}

#[test]
fn wrong_shapes_are_a_clear_error() {
    // The small graph has 4 output channels where VGG-16 has 64.
    let p = fixture("vgg/tiny_nchw.onnx");
    let e = read_vgg_onnx(&p).err().unwrap();
    match &e {
        VggError::WrongShape {
            index,
            found,
            expected,
            ..
        } => {
            assert_eq!(*index, 1);
            assert_eq!(found, &vec![4, 3, 3, 3]);
            assert_eq!(expected, &vec![64, 3, 3, 3]);
        }
        other => panic!("unexpected {other}"),
    }
    assert!(e.to_string().contains("tiny_nchw.onnx"));
}

/// `--precision bf16` against f32 on the real network and a real photo: the features of every
/// style layer, their Gram matrices and the input gradient of a style loss stay within stated
/// tolerances (BF16 keeps 8 bits of mantissa: each input is off by up to 2^-9 relative).
/// Without a BF16 engine (AMX or AVX-512 BF16), bf16 falls back to f32 and must give the very
/// same features.
#[test]
fn bf16_features_stay_close_to_f32_on_the_real_network() {
    use ins_conv::Precision;
    let device = Device::flex().autodiff();
    let f32_vgg = real_vgg(&device);
    let bf16_vgg = f32_vgg.clone().with_precision(Precision::Bf16);
    let x = npy_tensor4(&fixture("vgg/real_input.npy"), &device);
    let run = |vgg: &Vgg| layers_grams_and_gradient(vgg, &x, |g| g.powf_scalar(2.0).sum());
    let (fa, ga, da) = run(&f32_vgg);
    let (fb, gb, db) = run(&bf16_vgg);
    if Precision::Bf16.effective() == Precision::F32 {
        assert_eq!(
            fa, fb,
            "without a BF16 engine, bf16 must fall back to the f32 network"
        );
        return;
    }
    for (i, name) in vgg_import::VggFeatures::NAMES.iter().enumerate() {
        let feature = max_rel_diff(&fb[i], &fa[i], 1e-3);
        let gram = rel_l2(&gb[i], &ga[i]);
        eprintln!(
            "{name}: features {feature:.2e} of the layer's largest value, Gram {gram:.2e} (relative L2)"
        );
        assert!(
            feature > 0.0,
            "{name}: bf16 gave f32's exact values: not running in bf16?"
        );
        assert!(
            feature < 2e-2,
            "{name}: features differ by {feature} of the layer's largest value"
        );
        assert!(
            gram < 1e-2,
            "{name}: Gram matrices differ by {gram} (relative L2)"
        );
    }
    // The gradient passes through all ten layers twice in bf16 (features, then gradients):
    // measured 3.9e-2 here. The bound was set after that measurement; what a user sees is
    // checked end to end (a stylization's final Gram distance, README).
    let grad = rel_l2(&db, &da);
    eprintln!("input gradient: {grad:.2e} (relative L2)");
    assert!(
        grad < 5e-2,
        "input gradients differ by {grad} (relative L2)"
    );
}

/// The style layers of `x` through `vgg`, their Gram matrices, and the input gradient of the
/// sum over layers of `loss(Gram)`.
fn layers_grams_and_gradient(
    vgg: &Vgg,
    x: &Tensor<4>,
    loss: impl Fn(Tensor<3>) -> Tensor<1>,
) -> (Vec<Vec<f32>>, Vec<Vec<f32>>, Vec<f32>) {
    let x = x.clone().require_grad();
    let f = vgg.features(x.clone());
    let grams: Vec<Tensor<3>> = f
        .style_layers()
        .iter()
        .map(|t| ins_core::loss::gram((*t).clone()))
        .collect();
    let total = grams
        .iter()
        .map(|g| loss(g.clone()))
        .reduce(|a, b| a + b)
        .unwrap();
    let grad = x.grad(&total.backward()).unwrap();
    let layers: Vec<Vec<f32>> = f
        .style_layers()
        .iter()
        .map(|t| values((*t).clone().inner()))
        .collect();
    let grams: Vec<Vec<f32>> = grams.into_iter().map(|g| values(g.inner())).collect();
    (layers, grams, values(grad.inner()))
}

fn rel_l2(a: &[f32], b: &[f32]) -> f32 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let n: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (d / n).sqrt() as f32
}

/// `--precision f16` on wgpu against f32 on the same adapter, on a small VGG-shaped network
/// (the fixture's ten 3×3 convolutions, a few channels each) and a 64² crop of the real photo:
/// the style layers' features and the input gradient of a style loss. An adapter without f16
/// shaders falls back to f32 and must give the very same features. The f32 run is also held
/// to Flex's (the weights are stored channels-last on the GPU, `Vgg16Features::channels_last`).
/// The real VGG-16 runs the same check in
/// [`f16_features_on_the_real_network_stay_close_to_f32`], on a GPU.
#[test]
fn f16_features_on_wgpu_stay_close_to_f32() {
    f16_against_f32_on_wgpu(|device| {
        let w = read_vgg_like_onnx(&fixture("vgg/tiny_nchw.onnx"), None).unwrap();
        Vgg {
            net: Vgg16Features::from_weights(&w, device),
            preprocess: w.detected,
        }
    });
}

/// The same check on the real VGG-16, on wgpu, or on CUDA where `INS_GPU_TEST_BACKEND=cuda`.
/// On Mesa's lavapipe its f16 and f32 kernels took about 10 minutes of CI's time for what the
/// small network checks there in seconds, so it runs where it means something, on a GPU:
/// `scripts/gpu/check.sh` runs it (`--ignored`) on both backends.
#[test]
#[ignore = "the real VGG-16 in f16 on a GPU: scripts/gpu/check.sh runs it"]
fn f16_features_on_the_real_network_stay_close_to_f32() {
    f16_against_f32_on_wgpu(real_vgg);
}

/// Features and a style loss's input gradient of `network` in f16 against f32 on the wgpu
/// adapter, or CUDA's GPU where `INS_GPU_TEST_BACKEND=cuda` (see
/// [`f16_features_on_wgpu_stay_close_to_f32`]).
fn f16_against_f32_on_wgpu(network: fn(&Device) -> Vgg) {
    use ins_conv::Precision;
    use ins_core::backend::BackendChoice;
    let choice = match std::env::var("INS_GPU_TEST_BACKEND").as_deref() {
        Ok("cuda") => BackendChoice::Cuda,
        _ => BackendChoice::Wgpu,
    };
    let (features, gradients, half) = ins_tests::within(
        ins_tests::WGPU_LIMIT_S,
        "VGG on the GPU in f16 and f32",
        move || {
            let device = choice.device().autodiff();
            let half = Precision::F16.effective_on(&device) == Precision::F16;
            let f32_vgg = network(&device);
            let f16_vgg = f32_vgg.clone().with_precision(Precision::F16);
            // A 64² crop keeps lavapipe's time small.
            let x = npy_tensor4(&fixture("vgg/real_input.npy"), &device).slice([
                0..1,
                0..3,
                0..64,
                0..64,
            ]);
            // A style loss of the size stylization uses: Gram distances to a fixed target.
            let run = |vgg: &Vgg| {
                let (layers, _, grad) = layers_grams_and_gradient(vgg, &x, |g| {
                    (g.clone() - g.detach().mul_scalar(0.5))
                        .powf_scalar(2.0)
                        .mean()
                });
                (layers, grad)
            };
            let (fa, da) = run(&f32_vgg);
            let (fb, db) = run(&f16_vgg);
            (
                fa.iter()
                    .zip(&fb)
                    .map(|(a, b)| (a.clone(), b.clone()))
                    .collect::<Vec<_>>(),
                (da, db),
                half,
            )
        },
    );
    // The same network on Flex: the GPU's f32 features and gradient, channels-last weights
    // and all, are Flex's up to rounding.
    let flex = Device::flex().autodiff();
    let x = npy_tensor4(&fixture("vgg/real_input.npy"), &flex).slice([0..1, 0..3, 0..64, 0..64]);
    let loss = |g: Tensor<3>| {
        (g.clone() - g.detach().mul_scalar(0.5))
            .powf_scalar(2.0)
            .mean()
    };
    let (flex_layers, _, flex_grad) = layers_grams_and_gradient(&network(&flex), &x, loss);
    for (name, (f, (gpu, _))) in vgg_import::VggFeatures::NAMES
        .iter()
        .zip(flex_layers.iter().zip(&features))
    {
        let d = max_rel_diff(gpu, f, 1e-3);
        assert!(
            d < 1e-4,
            "{name}: the GPU's f32 features differ from Flex's by {d}"
        );
    }
    let grad = rel_l2(&gradients.0, &flex_grad);
    assert!(
        grad < 1e-4,
        "the GPU's f32 input gradient differs from Flex's by {grad} (relative L2)"
    );
    if !half {
        eprintln!("this adapter has no f16 shaders: f16 falls back to f32");
        for (a, b) in &features {
            assert_eq!(
                a, b,
                "without f16 shaders, f16 must fall back to the f32 network"
            );
        }
        return;
    }
    for (name, (a, b)) in vgg_import::VggFeatures::NAMES.iter().zip(&features) {
        let d = max_rel_diff(b, a, 1e-3);
        eprintln!("{name}: features {d:.2e} of the layer's largest value");
        assert!(
            d > 0.0,
            "{name}: f16 gave f32's exact values: not running in f16?"
        );
        assert!(
            d < 2e-2,
            "{name}: features differ by {d} of the layer's largest value"
        );
    }
    let grad = rel_l2(&gradients.1, &gradients.0);
    eprintln!("input gradient: {grad:.2e} (relative L2)");
    assert!(
        grad.is_finite() && grad < 5e-2,
        "input gradients differ by {grad} (relative L2)"
    );
}
