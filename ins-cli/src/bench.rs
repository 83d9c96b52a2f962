//! `ins-cli bench`: the fixed workloads of BENCHMARKS.md, one JSON line each.

use std::time::Instant;

use anyhow::{Result, bail};
use burn::prelude::*;
use burn::tensor::Distribution;
use clap::Args;
use ins_core::backend::BackendChoice;
use ins_core::data::plain_image::pixel_coordinates;
use ins_core::loss::{StyleTarget, content_loss, style_loss};
use ins_core::modules::cim::SirenCimConfig;
use ins_core::modules::ins::Ins;
use ins_core::modules::sim::SimConfig;
use ins_core::train::groups::{OptimGroups, Optimizable};
use vgg_import::Vgg16Features;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Workloads: vgg, siren (default: all implemented).
    workloads: Vec<String>,
    /// Backend.
    #[arg(long, default_value = "flex")]
    backend: BackendChoice,
    /// Timed steps (after one warm-up step); the median is reported.
    #[arg(long, default_value_t = 5)]
    steps: usize,
}

const STYLE_WEIGHT: f64 = 1e8;

pub fn run(args: BenchArgs) -> Result<()> {
    let workloads = if args.workloads.is_empty() {
        vec!["vgg".to_string(), "siren".to_string()]
    } else {
        args.workloads.clone()
    };
    let backend = args.backend.resolve();
    for w in &workloads {
        let device = backend.device().autodiff();
        device.seed(42);
        let times = match w.as_str() {
            "vgg" => bench_vgg(&device, args.steps)?,
            "siren" => bench_siren(&device, args.steps)?,
            "nerf-pretrain" | "nerf-stylize" => {
                bail!("workload {w} needs the NeRF variant, which is not implemented yet")
            }
            other => bail!("unknown workload {other:?} (known: vgg, siren)"),
        };
        let mut sorted = times.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let median = sorted[sorted.len() / 2];
        println!(
            "{}",
            serde_json::json!({
                "workload": w,
                "backend": backend.to_string(),
                "ms_per_step": (median * 10.0).round() / 10.0,
                "steps": times.len(),
                "min_ms": (sorted[0] * 10.0).round() / 10.0,
                "max_ms": (sorted[sorted.len() - 1] * 10.0).round() / 10.0,
                "peak_rss_mb": peak_rss_mb(),
            })
        );
    }
    Ok(())
}

/// Peak resident memory of this process (Linux), in MiB.
fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some((kb / 1024.0).round())
}

fn timed(steps: usize, mut step: impl FnMut() -> Result<()>) -> Result<Vec<f64>> {
    step()?;
    let mut times = Vec::with_capacity(steps);
    for _ in 0..steps.max(1) {
        let t = Instant::now();
        step()?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(times)
}

fn bench_vgg(device: &Device, steps: usize) -> Result<Vec<f64>> {
    let vgg = Vgg16Features::random(device);
    let target_img = Tensor::<4>::random([1, 3, 256, 256], Distribution::Uniform(0.0, 1.0), device);
    let tf = vgg.forward(target_img);
    let targets = StyleTarget::from_features(&tf).grams;
    let content = tf.relu2_2.detach();
    let x = Tensor::<4>::random([1, 3, 256, 256], Distribution::Uniform(0.0, 1.0), device);
    timed(steps, || {
        let x = x.clone().detach().require_grad();
        let f = vgg.forward(x.clone());
        let loss = style_loss(&f, &targets).mul_scalar(STYLE_WEIGHT) + content_loss(&f, &content);
        let grads = loss.backward();
        let g = x
            .grad(&grads)
            .ok_or_else(|| anyhow::anyhow!("no gradient reached the input"))?;
        let _ = g.sum().into_scalar::<f32>();
        Ok(())
    })
}

fn bench_siren(device: &Device, steps: usize) -> Result<Vec<f64>> {
    let vgg = Vgg16Features::random(device);
    let side = 128;
    let target_img =
        Tensor::<4>::random([1, 3, side, side], Distribution::Uniform(0.0, 1.0), device);
    let tf = vgg.forward(target_img);
    let targets = StyleTarget::from_features(&tf).grams;
    let content = tf.relu2_2.detach();
    let cim = SirenCimConfig::new().init(device);
    let sim = SimConfig::new(2).with_d_hidden(64).with_depth(2);
    let mut model = Some(Ins::new(cim, &sim, false, device));
    let coords = Tensor::<2>::from_data(
        TensorData::new(
            pixel_coordinates(side as u32, side as u32).into_flattened(),
            [side * side, 2],
        ),
        device,
    );
    let code = Tensor::<2>::from_floats([[1.0, 0.0]], device);
    let mut groups =
        OptimGroups::new(<Ins<ins_core::modules::cim::SirenCim> as Optimizable>::group_names());
    timed(steps, || {
        let m = model.take().expect("model");
        let rgb = m.forward(coords.clone(), code.clone());
        let img = rgb.reshape([1, side, side, 3]).permute([0, 3, 1, 2]);
        let f = vgg.forward(img);
        let loss = style_loss(&f, &targets).mul_scalar(STYLE_WEIGHT) + content_loss(&f, &content);
        let mut grads = loss.backward();
        let m = m.optimize(&mut grads, 1e-4, &mut groups);
        let _ = m.am.gamma.val().into_scalar::<f32>();
        model = Some(m);
        Ok(())
    })
}
