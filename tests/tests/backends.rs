//! The same seed, model and training step give the same loss and parameters on flex, ndarray
//! and wgpu (Mesa lavapipe where there is no GPU).

use burn::prelude::*;
use ins_core::backend::BackendChoice;
use ins_core::data::plain_image::pixel_coordinates;
use ins_core::loss::{StyleTarget, mse, style_loss};
use ins_core::modules::cim::SirenCim;
use ins_core::modules::ins::Ins;
use ins_core::train::checkpoint::{load_module_bytes, module_bytes};
use ins_core::train::groups::{OptimGroups, Optimizable};
use ins_models::siren::SirenRunConfig;
use ins_tests::{fixture, values};
use vgg_import::onnx::read_vgg_like_onnx;
use vgg_import::{Vgg, Vgg16Features};

const SIDE: usize = 16;

fn config() -> SirenRunConfig {
    SirenRunConfig {
        styles: vec!["a".into(), "b".into()],
        hidden: 32,
        depth: 2,
        sim_hidden: 16,
        ..Default::default()
    }
}

/// One step (pixel MSE + 10·style loss through a small VGG, both styles) on `backend`;
/// returns the loss and the parameters afterwards.
fn one_step(backend: BackendChoice, init: &[u8]) -> (f32, Vec<f32>) {
    let device = backend.device().autodiff();
    let cfg = config();
    let model: Ins<SirenCim> = load_module_bytes(
        cfg.build_model(&device),
        init.to_vec(),
        std::path::Path::new("init"),
    )
    .unwrap();
    let w = read_vgg_like_onnx(&fixture("vgg/tiny_nchw.onnx"), None).unwrap();
    let vgg = Vgg {
        net: Vgg16Features::from_weights(&w, &device),
        preprocess: w.detected,
    };
    let coords = Tensor::<2>::from_data(
        TensorData::new(
            pixel_coordinates(SIDE as u32, SIDE as u32).into_flattened(),
            [SIDE * SIDE, 2],
        ),
        &device,
    );
    let target: Vec<f32> = (0..SIDE * SIDE * 3)
        .map(|i| ((i * 7 % 13) as f32) / 12.0)
        .collect();
    let target = Tensor::<1>::from_data(TensorData::new(target, [SIDE * SIDE * 3]), &device)
        .reshape([1, SIDE * SIDE, 3]);
    let style_img = target
        .clone()
        .reshape([1, SIDE, SIDE, 3])
        .permute([0, 3, 1, 2]);
    let grams = StyleTarget::from_image(&vgg, style_img).grams;
    let codes = Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 1.0]], &device);
    let rgb = model.forward(coords, codes);
    let img = rgb
        .clone()
        .reshape([2, SIDE, SIDE, 3])
        .permute([0, 3, 1, 2]);
    let loss = mse(rgb, target.expand([2, SIDE * SIDE, 3]))
        + style_loss(&vgg.features(img), &grams).mul_scalar(10.0);
    let value = loss.clone().into_scalar::<f32>();
    let mut grads = loss.backward();
    let mut groups = OptimGroups::new(<Ins<SirenCim> as Optimizable>::group_names());
    let model = model.optimize(&mut grads, 1e-3, &mut groups);
    let mut params = values(model.cim.layers[0].linear.weight.val());
    params.extend(values(model.am.fuse.weight.val()));
    params.extend(values(model.head.weight.val()));
    params.extend(values(model.am.gamma.val()));
    params.extend(values(model.sim.layers[0].weight.val()));
    (value, params)
}

#[test]
fn flex_ndarray_and_wgpu_agree_on_a_training_step() {
    let flex = Device::flex();
    flex.seed(5);
    let init = module_bytes(&config().build_model(&flex)).unwrap();
    let (l_flex, p_flex) = one_step(BackendChoice::Flex, &init);
    assert!(l_flex.is_finite() && l_flex > 0.0);
    for backend in [BackendChoice::Ndarray, BackendChoice::Wgpu] {
        let (l, p) = one_step(backend, &init);
        let rel = (l - l_flex).abs() / l_flex;
        assert!(rel < 1e-4, "{backend}: loss {l} vs flex {l_flex}");
        // Adam's first step moves each parameter by about lr = 1e-3, so 1e-5 is 1% of a step.
        let d = p
            .iter()
            .zip(&p_flex)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(d < 1e-5, "{backend}: parameters differ from flex by {d}");
    }
}
