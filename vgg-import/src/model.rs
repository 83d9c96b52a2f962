//! The VGG-16 feature extractor up to relu4_3, as a Burn module (so it caches in Burn's format).

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::FloatDType;
use burn::tensor::activation::relu;
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;

use ins_conv::op::ConvParams;
use ins_conv::{Engine, Precision};

use crate::onnx::{VGG16_CHANNELS, VggWeights};
use crate::preprocess::Preprocess;

/// One 3×3, pad-1 convolution.
#[derive(Module, Debug)]
pub struct VggConv {
    /// `[out, in, 3, 3]`.
    pub weight: Param<Tensor<4>>,
    /// `[out]`.
    pub bias: Param<Tensor<1>>,
}

/// The first ten convolutions of VGG-16.
#[derive(Module, Debug)]
pub struct Vgg16Features {
    /// Convolutions in layer order.
    pub convs: Vec<VggConv>,
    /// The arithmetic of the convolutions (not part of the weights).
    #[module(skip)]
    pub precision: Precision,
}

/// The activations the losses use.
#[derive(Clone, Debug)]
pub struct VggFeatures {
    /// After conv1_2.
    pub relu1_2: Tensor<4>,
    /// After conv2_2 (the content layer).
    pub relu2_2: Tensor<4>,
    /// After conv3_3.
    pub relu3_3: Tensor<4>,
    /// After conv4_3.
    pub relu4_3: Tensor<4>,
}

impl VggFeatures {
    /// The four style layers, shallow to deep.
    pub fn style_layers(&self) -> [&Tensor<4>; 4] {
        [&self.relu1_2, &self.relu2_2, &self.relu3_3, &self.relu4_3]
    }

    /// Layer names in the order of [`VggFeatures::style_layers`].
    pub const NAMES: [&'static str; 4] = ["relu1_2", "relu2_2", "relu3_3", "relu4_3"];
}

impl Vgg16Features {
    /// A module of the right shapes filled with zeros (to load a cached record into).
    pub fn zeros(device: &Device) -> Self {
        let convs = (0..10)
            .map(|i| {
                let c_in = if i == 0 { 3 } else { VGG16_CHANNELS[i - 1] };
                let c_out = VGG16_CHANNELS[i];
                VggConv {
                    weight: Param::from_tensor(Tensor::zeros([c_out, c_in, 3, 3], device)),
                    bias: Param::from_tensor(Tensor::zeros([c_out], device)),
                }
            })
            .collect();
        Self {
            convs,
            precision: Precision::F32,
        }
    }

    /// The module holding `weights`, frozen (gradients still flow to the input).
    pub fn from_weights(weights: &VggWeights, device: &Device) -> Self {
        let convs = weights
            .convs
            .iter()
            .map(|(w, b)| VggConv {
                weight: Param::from_tensor(Tensor::from_data(w.clone(), device)),
                bias: Param::from_tensor(Tensor::from_data(b.clone(), device)),
            })
            .collect();
        Self {
            convs,
            precision: Precision::F32,
        }
        .channels_last()
    }

    /// The same weights, frozen, stored as the GPU backends' convolutions read them: each
    /// `[out, in, 3, 3]` weight kept contiguous as `[out, 3, 3, in]` and seen through a
    /// permuted view. On Flex (whose convolutions keep their own packed copy) only frozen.
    ///
    /// Why: Burn's CubeCL convolutions work channels-last. Given a contiguous weight, each
    /// call permutes it and copies it to make its channels contiguous, forward and again in
    /// the input's gradient (which reads the same layout): twenty copies of weights that never
    /// change, every stylization step. Through this view the permute finds them in place.
    pub fn channels_last(self) -> Self {
        let device = match self.convs.first() {
            Some(c) => c.weight.val().device(),
            None => return self.no_grad(),
        };
        if ins_conv::kernel_device(&device) {
            return self.no_grad();
        }
        let convs = self
            .convs
            .into_iter()
            .map(|c| {
                let w = c.weight.val().permute([0, 2, 3, 1]).into_data();
                VggConv {
                    weight: Param::from_tensor(
                        Tensor::<4>::from_data(w, &device).permute([0, 3, 1, 2]),
                    ),
                    bias: c.bias,
                }
            })
            .collect();
        Self {
            convs,
            precision: self.precision,
        }
        .no_grad()
    }

    /// The same network computing its convolutions at `precision`.
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    /// Runs a preprocessed `[B, 3, H, W]` batch to relu4_3. The features come out in f32
    /// whatever the convolutions computed in.
    pub fn forward(&self, x: Tensor<4>) -> VggFeatures {
        let opts = ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
        let precision = self.precision.effective_on(&x.device());
        let engine = match precision {
            Precision::Bf16 => Engine::bf16(),
            _ => None,
        };
        let half = precision == Precision::F16;
        let x = if half { x.cast(FloatDType::F16) } else { x };
        let conv = |i: usize, x: Tensor<4>| {
            let c = &self.convs[i];
            let (mut w, mut b) = (c.weight.val(), c.bias.val());
            if half {
                // Cast on use: the module keeps one f32 copy for every device and precision.
                (w, b) = (w.cast(FloatDType::F16), b.cast(FloatDType::F16));
            }
            match engine {
                // The ReLU is fused into the op (and its mask into the input gradient).
                Some(engine) => {
                    let params = ConvParams {
                        stride: [1, 1],
                        padding: [1, 1],
                        engine,
                        relu: true,
                        // VGG is frozen.
                        reuse_kernel: true,
                    };
                    ins_conv::conv2d(x, w, Some(b), params)
                }
                None => relu(conv2d(x, w, Some(b), opts.clone())),
            }
        };
        let out = |x: Tensor<4>| if half { x.cast(FloatDType::F32) } else { x };
        let pool = ins_conv::max_pool_2x2;
        let x = conv(0, x);
        let relu1_2 = conv(1, x);
        let x = conv(2, pool(relu1_2.clone()));
        let relu2_2 = conv(3, x);
        let x = conv(4, pool(relu2_2.clone()));
        let x = conv(5, x);
        let relu3_3 = conv(6, x);
        let x = conv(7, pool(relu3_3.clone()));
        let x = conv(8, x);
        let relu4_3 = conv(9, x);
        VggFeatures {
            relu1_2: out(relu1_2),
            relu2_2: out(relu2_2),
            relu3_3: out(relu3_3),
            relu4_3: out(relu4_3),
        }
    }
}

/// A ready feature extractor with its preprocessing.
#[derive(Clone, Debug)]
pub struct Vgg {
    /// The convolutions.
    pub net: Vgg16Features,
    /// The input convention of these weights.
    pub preprocess: Preprocess,
}

impl Vgg {
    /// Features of an RGB batch in [0, 1], `[B, 3, H, W]`.
    pub fn features(&self, rgb: Tensor<4>) -> VggFeatures {
        self.net.forward(self.preprocess.apply(rgb))
    }

    /// The same extractor computing its convolutions at `precision`.
    pub fn with_precision(self, precision: Precision) -> Self {
        Self {
            net: self.net.with_precision(precision),
            preprocess: self.preprocess,
        }
    }

    /// The same extractor on another device.
    pub fn to_device(&self, device: &Device) -> Self {
        Self {
            net: self.net.clone().to_device(device).channels_last(),
            preprocess: self.preprocess,
        }
    }
}

impl Vgg16Features {
    /// Random (He-initialised) weights of VGG-16's shapes, for benchmarks and tests that must
    /// not depend on downloaded weights.
    pub fn random(device: &Device) -> Self {
        use burn::tensor::Distribution;
        let convs = (0..10)
            .map(|i| {
                let c_in = if i == 0 { 3 } else { VGG16_CHANNELS[i - 1] };
                let c_out = VGG16_CHANNELS[i];
                let std = (2.0 / (9.0 * c_in as f64)).sqrt();
                VggConv {
                    weight: Param::from_tensor(Tensor::random(
                        [c_out, c_in, 3, 3],
                        Distribution::Normal(0.0, std),
                        device,
                    )),
                    bias: Param::from_tensor(Tensor::zeros([c_out], device)),
                }
            })
            .collect();
        Self {
            convs,
            precision: Precision::F32,
        }
        .channels_last()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn gradients_reach_the_input_and_never_the_frozen_weights() {
        let d = Device::flex().autodiff();
        d.seed(8);
        let vgg = Vgg16Features::random(&d);
        let x = Tensor::<4>::random([1, 3, 16, 16], Distribution::Default, &d).require_grad();
        let f = vgg.forward(x.clone());
        let loss = f.relu1_2.sum() + f.relu4_3.sum();
        let grads = loss.backward();
        assert!(x.grad(&grads).is_some(), "no gradient reached the input");
        for (i, c) in vgg.convs.iter().enumerate() {
            assert!(
                !c.weight.val().is_require_grad(),
                "conv {i} weight requires grad"
            );
            assert!(
                c.weight.val().grad(&grads).is_none(),
                "conv {i} weight got a gradient"
            );
            assert!(
                c.bias.val().grad(&grads).is_none(),
                "conv {i} bias got a gradient"
            );
        }
    }
}
