//! Reading VGG-16 convolution weights from an ONNX graph.
//!
//! Convolutions are taken by graph order, which for VGG-16 is layer order; every weight shape
//! is checked against VGG-16 (3×3 kernels, stride 1, padding 1, channels 64-64-128-128-256-256-
//! 256-512-512-512), and the max-pools between them must sit after convolutions 2, 4 and 7.

use std::path::{Path, PathBuf};

use burn::tensor::TensorData;
use onnx_ir::node::padding::{AutoPad, PaddingConfig2d};
use onnx_ir::{Node, OnnxGraphBuilder};

use crate::error::VggError;
use crate::preprocess::Preprocess;

/// Output channels of VGG-16's first ten convolutions.
pub const VGG16_CHANNELS: [usize; 10] = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512];
/// After which convolutions (1-based) VGG-16 max-pools.
pub const VGG16_POOL_AFTER: [usize; 3] = [2, 4, 7];

/// Memory layout of the graph's input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputLayout {
    /// NHWC with a leading Transpose (tf2onnx exports of Keras models).
    Nhwc,
    /// NCHW (torchvision / PyTorch exports).
    Nchw,
}

/// Weights of the first ten convolutions, and what the file says about its input.
pub struct VggWeights {
    /// (weight `[out, in, 3, 3]`, bias `[out]`) per convolution.
    pub convs: Vec<(TensorData, TensorData)>,
    /// Input layout of the graph.
    pub layout: InputLayout,
    /// The preprocessing the layout implies (NHWC/Keras → Caffe, NCHW → torch).
    pub detected: Preprocess,
}

/// Reads and checks the first ten convolutions of a VGG-16 ONNX file.
pub fn read_vgg_onnx(path: &Path) -> Result<VggWeights, VggError> {
    read_vgg_like_onnx(path, Some(&VGG16_CHANNELS))
}

/// Like [`read_vgg_onnx`], for VGG-shaped graphs of other widths: with `channels` `None`, the
/// output widths are read from the file and only their chaining (each convolution's input width
/// is the previous one's output width, the first takes 3) is checked. Used by tests with small
/// reference graphs.
pub fn read_vgg_like_onnx(
    path: &Path,
    channels: Option<&[usize; 10]>,
) -> Result<VggWeights, VggError> {
    let pb = || PathBuf::from(path);
    if !path.exists() {
        return Err(VggError::Missing { path: pb() });
    }
    // onnx-ir reports most problems as errors, but a malformed graph can still trip an
    // assertion inside it: turn that into an error naming the file too.
    let parsed =
        std::panic::catch_unwind(|| OnnxGraphBuilder::new().simplify(false).parse_file(path));
    let graph = match parsed {
        Ok(Ok(g)) => g,
        Ok(Err(e)) => {
            return Err(VggError::NotOnnx {
                path: pb(),
                reason: e.to_string(),
            });
        }
        Err(_) => {
            return Err(VggError::NotOnnx {
                path: pb(),
                reason: "the ONNX parser could not process this graph".into(),
            });
        }
    };

    // NHWC graphs (tf2onnx) transpose their input to NCHW before the first convolution; the
    // input's declared shape, when it has one, says the same.
    let transposed = graph
        .nodes
        .iter()
        .take_while(|n| !matches!(n, Node::Conv2d(_)))
        .any(|n| matches!(n, Node::Transpose(t) if t.config.perm == vec![0, 3, 1, 2]));
    let channels_last = graph
        .inputs
        .first()
        .and_then(|a| a.ty.static_shape())
        .is_some_and(|s| s.len() == 4 && s[3] == Some(3) && s[1] != Some(3));
    let layout = if transposed || channels_last {
        InputLayout::Nhwc
    } else {
        InputLayout::Nchw
    };

    let mut convs: Vec<(TensorData, TensorData)> = Vec::new();
    let mut pools_after = Vec::new();
    for node in &graph.nodes {
        match node {
            Node::Conv2d(conv) if convs.len() < 10 => {
                let index = convs.len() + 1;
                let name = conv.name.clone();
                let c_in = match convs.last() {
                    None => 3,
                    Some((w, _)) => w.shape()[0],
                };
                let declared = conv
                    .inputs
                    .get(1)
                    .and_then(|a| a.value())
                    .map(|w| w.shape().first().copied().unwrap_or(0));
                let c_out = match channels {
                    Some(ch) => ch[index - 1],
                    None => declared.unwrap_or(0),
                };
                let shape_err =
                    |what: &str, found: Vec<usize>, expected: Vec<usize>| VggError::WrongShape {
                        path: pb(),
                        index,
                        name: name.clone(),
                        what: what.into(),
                        found,
                        expected,
                    };
                let cfg = &conv.config;
                if cfg.kernel_size != [3, 3] {
                    return Err(shape_err("kernel", cfg.kernel_size.to_vec(), vec![3, 3]));
                }
                if cfg.stride != [1, 1] || cfg.dilation != [1, 1] || cfg.groups != 1 {
                    return Err(shape_err(
                        "stride/dilation/groups",
                        vec![cfg.stride[0], cfg.stride[1], cfg.dilation[0], cfg.groups],
                        vec![1, 1, 1, 1],
                    ));
                }
                let pads_ok = matches!(cfg.padding, PaddingConfig2d::Explicit(1, 1, 1, 1))
                    || matches!(cfg.auto_pad, AutoPad::SameUpper | AutoPad::SameLower);
                if !pads_ok {
                    return Err(VggError::NotVgg {
                        path: pb(),
                        reason: format!(
                            "convolution {index} ({name}) is not padded by 1 on each side"
                        ),
                    });
                }
                let weight = conv.inputs.get(1).and_then(|a| a.value()).ok_or_else(|| {
                    VggError::NoWeights {
                        path: pb(),
                        index,
                        name: name.clone(),
                        what: "weight".into(),
                    }
                })?;
                if weight.shape().to_vec().as_slice() != [c_out, c_in, 3, 3] {
                    return Err(shape_err(
                        "weight shape",
                        weight.shape().to_vec(),
                        vec![c_out, c_in, 3, 3],
                    ));
                }
                let bias = match conv.inputs.get(2).and_then(|a| a.value()) {
                    Some(b) => {
                        if b.shape().to_vec().as_slice() != [c_out] {
                            return Err(shape_err("bias shape", b.shape().to_vec(), vec![c_out]));
                        }
                        b
                    }
                    None => TensorData::new(vec![0.0f32; c_out], [c_out]),
                };
                convs.push((weight.convert::<f32>(), bias.convert::<f32>()));
            }
            Node::MaxPool2d(_) if convs.len() < 10 => pools_after.push(convs.len()),
            _ => {}
        }
    }
    if convs.len() < 10 {
        return Err(VggError::TooFewConvolutions {
            path: pb(),
            found: convs.len(),
        });
    }
    if pools_after != VGG16_POOL_AFTER {
        return Err(VggError::NotVgg {
            path: pb(),
            reason: format!(
                "max-pools follow convolutions {pools_after:?}, VGG-16 pools after {VGG16_POOL_AFTER:?}"
            ),
        });
    }
    let detected = match layout {
        InputLayout::Nhwc => Preprocess::Caffe,
        InputLayout::Nchw => Preprocess::Torch,
    };
    Ok(VggWeights {
        convs,
        layout,
        detected,
    })
}
