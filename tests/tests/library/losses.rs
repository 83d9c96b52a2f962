//! Style / content losses: zero where they must be, and gradients that agree with finite
//! differences, on bare features and through a VGG network down to the input image.

use burn::prelude::*;
use burn::tensor::Distribution;
use ins_core::loss::{StyleTarget, content_loss, gram, style_loss};
use ins_tests::{fixture, values};
use vgg_import::onnx::read_vgg_like_onnx;
use vgg_import::{Vgg, Vgg16Features, VggFeatures};

fn random_features(device: &Device, seed: u64) -> VggFeatures {
    device.seed(seed);
    let r = |c, s| Tensor::<4>::random([1, c, s, s], Distribution::Uniform(0.0, 1.0), device);
    VggFeatures {
        relu1_2: r(3, 8),
        relu2_2: r(4, 6),
        relu3_3: r(5, 4),
        relu4_3: r(6, 2),
    }
}

#[test]
fn gram_is_normalised_outer_product() {
    let device = Device::flex();
    let f = Tensor::<4>::from_floats(
        [[[[1.0, 2.0], [3.0, 4.0]], [[0.0, 1.0], [0.0, 1.0]]]],
        &device,
    );
    let g = values(gram(f));
    // C·H·W = 8. Row 0·row 0 = 30, row 0·row 1 = 6, row 1·row 1 = 2.
    let expected = [30.0 / 8.0, 6.0 / 8.0, 6.0 / 8.0, 2.0 / 8.0];
    for (a, b) in g.iter().zip(expected) {
        assert!((a - b).abs() < 1e-6, "{g:?}");
    }
}

#[test]
fn style_loss_is_zero_for_identical_inputs_and_positive_otherwise() {
    let device = Device::flex();
    let f = random_features(&device, 1);
    let t = StyleTarget::from_features(&f).grams;
    let same = style_loss(&f, &t).into_scalar::<f32>();
    assert_eq!(same, 0.0);
    let other = random_features(&device, 2);
    assert!(style_loss(&other, &t).into_scalar::<f32>() > 0.0);
    assert_eq!(content_loss(&f, &f.relu2_2).into_scalar::<f32>(), 0.0);
}

/// Central finite difference of `loss` at element `i` of `x`, in f64 arithmetic on f32 inputs.
fn finite_difference(
    x: &[f32],
    shape: [usize; 4],
    i: usize,
    eps: f32,
    loss: &dyn Fn(Tensor<4>) -> f32,
    device: &Device,
) -> f64 {
    let eval = |delta: f32| {
        let mut v = x.to_vec();
        v[i] += delta;
        loss(Tensor::<1>::from_data(TensorData::new(v, [x.len()]), device).reshape(shape)) as f64
    };
    (eval(eps) - eval(-eps)) / (2.0 * eps as f64)
}

#[test]
fn style_and_content_gradients_match_finite_differences() {
    let plain = Device::flex();
    let ad = plain.clone().autodiff();
    let target = random_features(&plain, 3);
    let grams = StyleTarget::from_features(&target)
        .grams
        .map(|g| g.to_device(&ad));
    let content = target.relu2_2.clone().to_device(&ad);
    let x_feat = random_features(&plain, 4);
    let shape = [1, 4, 6, 6];
    let x = values(x_feat.relu2_2.clone());
    // The loss as a function of relu2_2 (other layers fixed).
    let loss_of = |t: Tensor<4>| -> Tensor<1> {
        let f = VggFeatures {
            relu1_2: x_feat.relu1_2.clone().to_device(&t.device()),
            relu2_2: t,
            relu3_3: x_feat.relu3_3.clone().to_device(&ad),
            relu4_3: x_feat.relu4_3.clone().to_device(&ad),
        };
        style_loss(&f, &grams).mul_scalar(100.0) + content_loss(&f, &content)
    };
    let xt = Tensor::<1>::from_data(TensorData::new(x.clone(), [x.len()]), &ad)
        .reshape(shape)
        .require_grad();
    let grads = loss_of(xt.clone()).backward();
    let g = values(xt.grad(&grads).unwrap());
    let eval = |t: Tensor<4>| loss_of(t.to_device(&ad)).into_scalar::<f32>();
    for i in [0, 7, 33, 71, 143] {
        let fd = finite_difference(&x, shape, i, 1e-2, &eval, &ad);
        let rel = (g[i] as f64 - fd).abs() / fd.abs().max(1e-3);
        assert!(
            rel < 0.02,
            "element {i}: autodiff {} vs finite difference {fd}",
            g[i]
        );
    }
}

#[test]
fn gradient_through_vgg_to_the_image_matches_finite_differences() {
    let plain = Device::flex();
    let ad = plain.clone().autodiff();
    let w = read_vgg_like_onnx(&fixture("vgg/tiny_nchw.onnx"), None).unwrap();
    let vgg = Vgg {
        net: Vgg16Features::from_weights(&w, &ad),
        preprocess: w.detected,
    };
    plain.seed(9);
    let style = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &ad);
    let sf = vgg.features(style);
    let grams = StyleTarget::from_features(&sf).grams;
    let content = sf.relu2_2.detach();
    let shape = [1, 3, 16, 16];
    let x: Vec<f32> = (0..3 * 16 * 16)
        .map(|i| ((i * 37 % 101) as f32) / 100.0)
        .collect();
    let loss_of = |t: Tensor<4>| {
        let f = vgg.features(t);
        style_loss(&f, &grams).mul_scalar(1e3) + content_loss(&f, &content)
    };
    let xt = Tensor::<1>::from_data(TensorData::new(x.clone(), [x.len()]), &ad)
        .reshape(shape)
        .require_grad();
    let grads = loss_of(xt.clone()).backward();
    let g = values(xt.grad(&grads).unwrap());
    let eval = |t: Tensor<4>| loss_of(t).into_scalar::<f32>();
    let mut checked = 0;
    for i in [5, 100, 300, 517, 700] {
        let fd = finite_difference(&x, shape, i, 5e-3, &eval, &ad);
        if fd.abs() < 1e-4 {
            continue; // a ReLU kink or a flat spot: the derivative is not informative here
        }
        checked += 1;
        let rel = (g[i] as f64 - fd).abs() / fd.abs();
        assert!(
            rel < 0.05,
            "pixel {i}: autodiff {} vs finite difference {fd}",
            g[i]
        );
    }
    assert!(checked >= 3, "too few informative pixels");
}
