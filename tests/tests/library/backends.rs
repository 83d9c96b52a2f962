//! The same seed, model and loss give the same loss value and the same gradients on flex and
//! wgpu (Mesa lavapipe where there is no GPU). Gradients, not an Adam step: Adam's
//! first step is ≈ lr·sign(g) and would hide an error in the gradient's magnitude.
//!
//! An earlier session saw wgpu's backward deadlock in-process here (Burn 0.22.1 / CubeCL 0.11.3,
//! the fused-matmul autotuner waiting for exclusive device access). Since the wgpu runtime is
//! set up before its first tensor (`ins_core::gpu`), it ran through twice: with the program's
//! settings, and with CubeCL's defaults and no tuning cache. Each backend runs under a timeout,
//! so a deadlock fails this test instead of hanging the suite.

use burn::prelude::*;
use ins_core::backend::BackendChoice;
use ins_core::loss::{StyleTarget, mse, style_loss};
use ins_core::modules::cim::SirenCim;
use ins_core::modules::ins::Ins;
use ins_core::train::checkpoint::{load_module_bytes, module_bytes};
use ins_models::siren::SirenRunConfig;
use ins_scene::data::plain_image::pixel_coordinates;
use ins_tests::{fixture, max_rel_diff, values};
use vgg_import::onnx::read_vgg_like_onnx;
use vgg_import::{Vgg, Vgg16Features};

const SIDE: usize = 16;

fn config() -> SirenRunConfig {
    let mut cfg = SirenRunConfig {
        hidden: 32,
        depth: 2,
        sim_hidden: 16,
        ..Default::default()
    };
    cfg.style.styles = vec!["a".into(), "b".into()];
    cfg
}

/// Pixel MSE + 10·style loss through a small VGG, both styles, on `backend`; returns the loss
/// and the gradients of parameters of every module (CIM, AM, head, γ, SIM).
fn loss_and_gradients(backend: BackendChoice, init: &[u8]) -> (f32, Vec<Vec<f32>>) {
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
    let grads = loss.backward();
    let g = |t: Tensor<2>| values(t.grad(&grads).expect("gradient"));
    let grads = vec![
        g(model.cim.layers[0].linear.weight.val()),
        g(model.am.fuse.weight.val()),
        g(model.head.weight.val()),
        values(model.am.gamma.val().grad(&grads).expect("γ gradient")),
        g(model.sim.layers[0].weight.val()),
    ];
    (value, grads)
}

#[test]
fn flex_and_wgpu_agree_on_loss_and_gradients() {
    // SIREN's hidden products run in bf16 on flex where the CPU has AVX-512 BF16: compare f32.
    let _f32 = ins_core::kernels::dense_bf16::forbid();
    let flex = Device::flex();
    flex.seed(5);
    let mut cfg = config().build_model(&flex);
    // Leave the identity start so that SIM and AM get gradients too.
    cfg.am.gamma = burn::module::Param::from_tensor(Tensor::from_floats([0.6], &flex));
    let init = module_bytes(&cfg).unwrap();
    let (l_flex, g_flex) = loss_and_gradients(BackendChoice::Flex, &init);
    assert!(l_flex.is_finite() && l_flex > 0.0);
    for g in &g_flex {
        assert!(g.iter().any(|v| *v != 0.0), "a gradient is zero on flex");
    }
    let (l, g) = ins_tests::within(ins_tests::WGPU_LIMIT_S, "the wgpu loss", move || {
        loss_and_gradients(BackendChoice::Wgpu, &init)
    });
    let rel = (l - l_flex).abs() / l_flex;
    assert!(rel < 1e-4, "wgpu: loss {l} vs flex {l_flex}");
    assert_eq!(g.len(), g_flex.len());
    for (i, (a, b)) in g.iter().zip(&g_flex).enumerate() {
        let d = max_rel_diff(a, b, 1e-12);
        assert!(
            d < 1e-4,
            "wgpu: gradient {i} differs from flex by {d} (relative to its largest entry)"
        );
    }
}

/// `len` values of `sin(j·k)`: inputs whose every entry differs, the same on every device.
fn wave(len: usize, k: f32) -> Vec<f32> {
    (0..len).map(|j| (j as f32 * k).sin()).collect()
}

/// A trained layer in blocks of rows (`kernels::dense_blocks`, what a GPU runs: the weight
/// gradient as a batch of partial products, summed; the bias added a block, its gradient summed
/// over each block's rows, then over the blocks) gives on wgpu (with Burn's fusion) flex's plain
/// layer's value and input, weight and bias gradients: at odd widths, and at widths of four
/// whose kernels read four values at a time, as the program's layers do.
#[test]
fn a_trained_layer_in_blocks_of_rows_on_wgpu_matches_flex() {
    for (n, i, o) in [(4_096usize, 27usize, 45usize), (4_096, 32, 64)] {
        let blocks = ins_core::kernels::dense_blocks::row_blocks(n, i, o);
        assert_eq!(blocks, 16);
        layer_in_blocks_matches_flex(n, i, o, blocks);
    }
}

/// A Gram matrix summed in blocks of pixels (`loss::gram::gram_in_blocks`, what a GPU runs) gives
/// on wgpu flex's Gram matrix and its gradient, at relu1_2's 64 channels.
#[test]
fn a_gram_matrix_in_blocks_of_pixels_on_wgpu_matches_flex() {
    use ins_core::loss::gram::{gram, gram_in_blocks};
    let (c, h, w) = (64usize, 32usize, 64usize);
    let blocks = ins_core::kernels::dense_blocks::row_blocks(h * w, c, c);
    assert_eq!(blocks, 8);
    let (f, probe) = (wave(c * h * w, 0.37), wave(c * c, 1.3));
    let run = move |device: Device, blocks: usize| -> Vec<Vec<f32>> {
        let f = Tensor::<1>::from_floats(f.as_slice(), &device)
            .reshape([1, c, h, w])
            .require_grad();
        let g = match blocks {
            1 => gram(f.clone()),
            _ => gram_in_blocks(f.clone().reshape([1, c, h * w]), blocks)
                .mul_scalar(1.0 / (c * h * w) as f32),
        };
        let probe = Tensor::<1>::from_floats(probe.as_slice(), &device).reshape([1, c, c]);
        let grads = (g.clone() * probe).sum().backward();
        vec![values(g), values(f.grad(&grads).expect("feature gradient"))]
    };
    let flex = run(Device::flex().autodiff(), 1);
    let wgpu = ins_tests::within(
        ins_tests::WGPU_LIMIT_S,
        "a Gram matrix in blocks",
        move || run(BackendChoice::Wgpu.device().autodiff(), blocks),
    );
    for (k, what) in ["value", "feature gradient"].iter().enumerate() {
        let err = max_rel_diff(&wgpu[k], &flex[k], 1e-6);
        assert!(err < 1e-4, "{what}: {err:e} relative to the largest");
    }
}

fn layer_in_blocks_matches_flex(n: usize, i: usize, o: usize, blocks: usize) {
    use ins_core::kernels::dense::dense_with;
    use ins_core::kernels::dense_blocks::affine_in_blocks;
    let _f32 = ins_core::kernels::dense_bf16::forbid();
    let (x, w, b, probe) = (
        wave(n * i, 0.37),
        wave(i * o, 1.3),
        wave(o, 2.1),
        wave(n * o, 0.11),
    );
    let run = move |device: Device, blocks: usize| -> Vec<Vec<f32>> {
        let t = |v: &[f32], shape: [usize; 2]| Tensor::<1>::from_floats(v, &device).reshape(shape);
        let x = t(&x, [n, i]).require_grad();
        let w = t(&w, [i, o]).require_grad();
        let b = Tensor::<1>::from_floats(b.as_slice(), &device).require_grad();
        let y = match blocks {
            1 => dense_with(x.clone(), w.clone(), b.clone()),
            _ => affine_in_blocks(x.clone(), w.clone(), Some(b.clone()), blocks),
        };
        let grads = (y.clone() * t(&probe, [n, o])).sum().backward();
        vec![
            values(y),
            values(x.grad(&grads).expect("input gradient")),
            values(w.grad(&grads).expect("weight gradient")),
            values(b.grad(&grads).expect("bias gradient")),
        ]
    };
    let flex = run(Device::flex().autodiff(), 1);
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "a layer in blocks", move || {
        run(BackendChoice::Wgpu.device().autodiff(), blocks)
    });
    for (k, what) in [
        "value",
        "input gradient",
        "weight gradient",
        "bias gradient",
    ]
    .iter()
    .enumerate()
    {
        let err = max_rel_diff(&wgpu[k], &flex[k], 1e-6);
        assert!(
            err < 1e-4,
            "{n}×{i}→{o}, {what}: {err:e} relative to the largest"
        );
    }
}

/// A small MLP's layers fused (`kernels::fused_mlp`, what the GPU backends run for the grid
/// NeRF's, SIM's and AM's chains: a unit a row forward and backward, a cube a block of rows for
/// the parameters' sums) give on wgpu flex's layers' values and the gradients of the input and
/// of every weight and bias: two layers (the stand-in third never read), three with a ReLU
/// after the last, and five split into pieces of three and two by `dense_chain_with`, over
/// rows that leave the last block of sums short.
#[test]
fn a_fused_mlp_on_wgpu_matches_flex_layer_by_layer() {
    fused_chain_matches_flex(600, &[32, 64, 16], &[true, false], false);
    fused_chain_matches_flex(300, &[31, 64, 64, 3], &[true, true, true], false);
    fused_chain_matches_flex(257, &[20, 48, 64, 64, 40, 3], &[true; 5], true);
}

fn fused_chain_matches_flex(n: usize, widths: &[usize], relu: &[bool], via_chain: bool) {
    use ins_core::kernels::dense::dense_with;
    use ins_core::kernels::dense_chain::dense_chain_with;
    use ins_core::kernels::fused_mlp::op::fused_mlp;
    let _f32 = ins_core::kernels::dense_bf16::forbid();
    let (widths, relu) = (widths.to_vec(), relu.to_vec());
    let (last, last_relu) = (widths[widths.len() - 1], relu[relu.len() - 1]);
    let x = wave(n * widths[0], 0.37);
    let probe = wave(n * last, 0.11);
    // Weights small enough that the ReLUs cut some units and pass others.
    let params: Vec<(Vec<f32>, Vec<f32>)> = widths
        .windows(2)
        .enumerate()
        .map(|(l, io)| {
            let scale = 1.0 / (io[0] as f32).sqrt();
            let w = wave(io[0] * io[1], 1.3 + l as f32);
            let b = wave(io[1], 2.1 + l as f32);
            (
                w.iter().map(|v| v * scale).collect(),
                b.iter().map(|v| v * 0.2).collect(),
            )
        })
        .collect();
    let run = move |device: Device, fused: bool| -> Vec<Vec<f32>> {
        let t = |v: &[f32], shape: [usize; 2]| Tensor::<1>::from_floats(v, &device).reshape(shape);
        let x = t(&x, [n, widths[0]]).require_grad();
        let layers: Vec<(Tensor<2>, Tensor<1>, bool)> = params
            .iter()
            .zip(widths.windows(2))
            .zip(&relu)
            .map(|(((w, b), io), &r)| {
                let w = t(w, [io[0], io[1]]).require_grad();
                let b = Tensor::<1>::from_floats(b.as_slice(), &device).require_grad();
                (w, b, r)
            })
            .collect();
        let y = match (fused, via_chain) {
            (true, true) => dense_chain_with(x.clone(), layers.clone()),
            (true, false) => fused_mlp(x.clone(), &layers),
            (false, _) => layers.iter().fold(x.clone(), |h, (w, b, r)| {
                let h = dense_with(h, w.clone(), b.clone());
                if *r {
                    burn::tensor::activation::relu(h)
                } else {
                    h
                }
            }),
        };
        let grads = (y.clone() * t(&probe, [n, last])).sum().backward();
        let mut out = vec![values(y), values(x.grad(&grads).expect("input gradient"))];
        for (w, b, _) in &layers {
            out.push(values(w.grad(&grads).expect("weight gradient")));
            out.push(values(b.grad(&grads).expect("bias gradient")));
        }
        out
    };
    let flex = run(Device::flex().autodiff(), false);
    let wgpu = ins_tests::within(ins_tests::WGPU_LIMIT_S, "a fused MLP", move || {
        run(BackendChoice::Wgpu.device().autodiff(), true)
    });
    let cut = flex[0].iter().filter(|v| **v == 0.0).count();
    assert!(
        !last_relu || (cut > 0 && cut < flex[0].len()),
        "the last ReLU cut {cut} of {} outputs",
        flex[0].len()
    );
    for (k, (a, b)) in wgpu.iter().zip(&flex).enumerate() {
        let what = match k {
            0 => "value".to_string(),
            1 => "input gradient".to_string(),
            k => format!("layer {}'s {}", (k - 2) / 2, ["weights", "bias"][k % 2]),
        };
        let err = max_rel_diff(a, b, 1e-6);
        assert!(
            err < 1e-4,
            "{n} rows, {what}: {err:e} relative to the largest"
        );
    }
}
