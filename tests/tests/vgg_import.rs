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
