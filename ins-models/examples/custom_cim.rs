//! The library API for custom INRs: a content module of your own (here a ReLU MLP over Gaussian
//! random Fourier features, Tancik et al. 2020) composed with INS's SIM and AM, trained and
//! stylized by the shared trainer.
//!
//! cargo run --release -p ins-models --example custom_cim [-- OUT_DIR]

use anyhow::Result;
use burn::module::Param;
use burn::prelude::*;
use burn::tensor::Distribution;
use ins_core::loss::{PerceptualLoss, StyleLoss};
use ins_core::modules::cim::ContentModule;
use ins_core::modules::ins::Ins;
use ins_core::modules::mlp::{ReluMlp, ReluMlpConfig};
use ins_core::modules::sim::SimConfig;
use ins_core::train::{Phase, TrainOptions, Trainer};
use ins_models::demo::{demo_content, demo_style};
use ins_models::image_task::{ImageObjective, ImageTask, render_image};
use ins_scene::patches::PatchSpec;

/// `x ↦ MLP([sin(2πBx), cos(2πBx)])` with a fixed random B.
#[derive(Module, Debug)]
struct GaussianFourierCim {
    b: Param<Tensor<2>>,
    mlp: ReluMlp,
}

impl GaussianFourierCim {
    fn new(n_features: usize, scale: f64, device: &Device) -> Self {
        let b = Tensor::random([2, n_features], Distribution::Normal(0.0, scale), device);
        Self {
            // B is a fixed projection, not a trained parameter.
            b: Param::from_tensor(b).set_require_grad(false),
            mlp: ReluMlpConfig::new(2 * n_features, 128, 3).init(device),
        }
    }
}

impl ContentModule for GaussianFourierCim {
    fn d_features(&self) -> usize {
        128
    }

    fn features(&self, coords: Tensor<2>) -> Tensor<2> {
        let proj = coords
            .matmul(self.b.val())
            .mul_scalar(std::f32::consts::TAU);
        self.mlp
            .forward(Tensor::cat(vec![proj.clone().sin(), proj.cos()], 1))
    }
}

fn main() -> Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "runs/custom_cim".into());
    let device = Device::flex();
    let ad = device.clone().autodiff();
    ad.seed(1);
    let vgg = vgg_import::load_vgg(
        &vgg_import::VggSource {
            fetch_if_missing: true,
            ..Default::default()
        },
        &ad,
    )?;
    let content = demo_content(96);
    let style = demo_style(128);
    let weights =
        ins_core::loss::LossWeights::default_for(vgg.preprocess, ins_core::loss::StyleLoss::Gram);
    let model = Ins::new(
        GaussianFourierCim::new(64, 6.0, &ad),
        &SimConfig::new(1),
        true,
        &ad,
    );
    let perceptual = PerceptualLoss::new(vgg, &[style], 128, StyleLoss::Gram, &ad);
    let mut task = ImageTask::<GaussianFourierCim>::new(
        content.clone(),
        perceptual,
        96 * 96,
        PatchSpec::new(96, 1),
        &ad,
    )?;
    let phases = vec![
        // Fitting trains the content path; SIM and AM wait for stylization.
        Phase::new("fit", ImageObjective::Fit, 300, 1e-3)
            .weight("mse", 1.0)
            .freeze("sim")
            .freeze("am"),
        Phase::new("stylize", ImageObjective::Stylize, 150, 1e-3)
            .weight("style", weights.style)
            .weight("content", weights.content),
    ];
    let mut opts = TrainOptions::new(&out);
    opts.checkpoint_every = 0;
    let outcome = Trainer::new(phases, opts).run(&mut task, model)?;
    let img = render_image(&outcome.model.valid(), 192, 192, &[1.0], &device)?;
    let path = std::path::Path::new(&out).join("stylized_192.png");
    img.save(&path)?;
    println!(
        "{} ({} steps in {:.1} s)",
        path.display(),
        outcome.steps,
        outcome.seconds
    );
    Ok(())
}
