//! `ins-cli bench`: the fixed workloads of `docs/benchmarks.md`, one JSON line each.
//!
//! Every workload that trains is a step of a variant's own task and phase, taken by the
//! trainer's [`ins_core::train::Stepper`] (the task's terms weighted by the phase, backward,
//! Adam), on small synthetic inputs written for the occasion; `hash-grid` and `vgg-layers` time
//! single operations.

mod dense;
mod hash_grid;
mod idr_pretrain;
mod nerf_grid;
mod nerf_grid_stylize;
mod nerf_pretrain;
mod nerf_stylize;
mod scenes;
mod siren;
mod vgg;
mod vgg_layers;

use std::time::Instant;

use anyhow::{Result, bail};
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use clap::Args;
use ins_conv::Precision;
use ins_core::train::{Phase, Stepper, Task};

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Workloads: vgg, vgg-layers (per-convolution profile), siren, nerf-pretrain, nerf-stylize,
    /// nerf-grid, nerf-grid-stylize (the default stylization step: grid NeRF, guided NNFM),
    /// hash-grid, hash-grid-object (its points inside a small object), hash-grid-reference,
    /// idr-pretrain, dense (one 64-wide layer; default: vgg, siren, nerf-pretrain,
    /// nerf-stylize, nerf-grid).
    workloads: Vec<String>,
    #[command(flatten)]
    device: crate::common::DeviceArgs,
    /// Timed steps (after one warm-up step); the median is reported.
    #[arg(long, default_value_t = 5)]
    steps: usize,
    /// Arithmetic of the VGG convolutions: f32, bf16 (flex, with AMX or AVX-512 BF16; f32 where
    /// the CPU has neither) or f16 (CUDA, and wgpu where the adapter has f16 shaders). Default: bf16
    /// where the CPU can, as in training. f32 also keeps a NeRF's dense products in f32.
    #[arg(long)]
    precision: Option<Precision>,
}

/// What a workload measured: milliseconds per timed step, and the rays (or points) of a step
/// where it has them.
pub struct Timing {
    /// One entry per timed step.
    pub times: Vec<f64>,
    /// Rays or points per step.
    pub rays: Option<f64>,
    /// Off a CPU, milliseconds per step over as many steps again taken back to back with one
    /// sync at the end (the loss left on the device, as the trainer does between its reads):
    /// how PyTorch's reference times a GPU, where the steps overlap. The timed steps above
    /// each wait for the device.
    pub pipelined: Option<f64>,
}

const KNOWN: &str = "vgg, vgg-layers, siren, nerf-pretrain, nerf-stylize, nerf-grid, nerf-grid-stylize, hash-grid, hash-grid-object, hash-grid-reference, idr-pretrain, dense";

pub fn run(args: BenchArgs) -> Result<()> {
    let workloads = if args.workloads.is_empty() {
        ["vgg", "siren", "nerf-pretrain", "nerf-stylize", "nerf-grid"]
            .map(String::from)
            .to_vec()
    } else {
        args.workloads.clone()
    };
    let backend = args.device.backend.resolve();
    let precision = args.precision.unwrap_or(Precision::Bf16.effective());
    let _products = (precision == Precision::F32).then(ins_core::kernels::dense_bf16::forbid);
    for w in &workloads {
        let device = backend.try_device()?.autodiff();
        device.seed(42);
        if w == "vgg-layers" {
            vgg_layers::run(&device, &backend.to_string(), args.steps, precision)?;
            continue;
        }
        let timing = match w.as_str() {
            "vgg" => vgg::run(&device, args.steps, precision)?,
            "siren" => siren::run(&device, args.steps, precision)?,
            "nerf-pretrain" => nerf_pretrain::run(&device, args.steps)?,
            "nerf-stylize" => nerf_stylize::run(&device, args.steps, precision)?,
            "nerf-grid" => nerf_grid::run(&device, args.steps)?,
            "nerf-grid-stylize" => nerf_grid_stylize::run(&device, args.steps, precision)?,
            "hash-grid" => hash_grid::run(&device, args.steps, true, hash_grid::Points::Spread)?,
            "hash-grid-object" => {
                hash_grid::run(&device, args.steps, true, hash_grid::Points::Object)?
            }
            "hash-grid-reference" => {
                hash_grid::run(&device, args.steps, false, hash_grid::Points::Spread)?
            }
            "idr-pretrain" => idr_pretrain::run(&device, args.steps)?,
            "dense" => dense::run(&device, args.steps, precision != Precision::F32)?,
            other => bail!("unknown workload {other:?} (known: {KNOWN})"),
        };
        let mut sorted = timing.times.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let median = sorted[sorted.len() / 2];
        let mut line = serde_json::json!({
            "workload": w,
            "backend": backend.to_string(),
            "ms_per_step": (median * 10.0).round() / 10.0,
            "steps": sorted.len(),
            "min_ms": (sorted[0] * 10.0).round() / 10.0,
            "max_ms": (sorted[sorted.len() - 1] * 10.0).round() / 10.0,
            "peak_rss_mb": peak_rss_mb(),
        });
        if matches!(
            w.as_str(),
            "vgg" | "siren" | "nerf-stylize" | "nerf-grid-stylize"
        ) {
            line["precision"] = precision.effective_on(&device).to_string().into();
        }
        if matches!(w.as_str(), "nerf-grid-stylize" | "dense") {
            let bf16 = precision != Precision::F32 && ins_core::kernels::dense_bf16::available();
            line["products"] = if bf16 { "bf16" } else { "f32" }.into();
        }
        if backend != ins_core::backend::BackendChoice::Flex {
            line["device_handle"] = ins_core::gpu::device_handle_name().into();
            line["split_rows"] = ins_core::kernels::dense_blocks::applies().into();
            line["fused_mlp"] = ins_core::kernels::fused_mlp::asked().into();
        }
        if let Some(rays) = timing.rays {
            line["rays_per_s"] = ((rays / median * 1e3).round()).into();
        }
        if let Some(ms) = timing.pipelined {
            line["pipelined_ms_per_step"] = ((ms * 10.0).round() / 10.0).into();
        }
        println!("{line}");
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

/// Milliseconds of each of `steps` calls of `step`, after one warm-up call.
pub fn timed(steps: usize, mut step: impl FnMut() -> Result<()>) -> Result<Vec<f64>> {
    step()?;
    let mut times = Vec::with_capacity(steps);
    for _ in 0..steps.max(1) {
        let t = Instant::now();
        step()?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(times)
}

/// The model's first float parameter, flattened.
fn first_param<M: Module>(model: &M) -> Option<Tensor<1>> {
    struct First(Option<Tensor<1>>);
    impl ModuleVisitor for First {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if self.0.is_none() {
                self.0 = Some(param.val().flatten::<1>(0, D - 1));
            }
        }
    }
    let mut v = First(None);
    model.visit(&mut v);
    v.0
}

/// Reads one value of the model's first parameter, so an asynchronous backend has finished the
/// update before the clock stops.
fn sync<M: Module>(model: &M) {
    if let Some(p) = first_param(model) {
        let _ = p.slice([0..1]).into_scalar::<f32>();
    }
}

/// Times `steps` training steps of `phase` on `task` from `model`, as the trainer takes them.
/// `rays` reads a step's ray count from its metrics, where the workload reports one.
pub fn time_task<T: Task>(
    task: &mut T,
    model: T::Model,
    phase: Phase<T::Objective>,
    steps: usize,
    rays: Option<&str>,
) -> Result<Timing> {
    let terms = task.terms(phase.objective);
    let (mut stepper, model) = Stepper::new(phase, model, terms)?;
    let mut model = Some(model);
    let mut counted = Vec::new();
    let times = timed(steps, || {
        let m = model.take().ok_or_else(|| anyhow::anyhow!("model"))?;
        let (m, _, metrics) = stepper.step(task, m)?;
        sync(&m);
        if let Some(name) = rays {
            counted.extend(metrics.iter().filter(|(n, _)| n == name).map(|(_, v)| *v));
        }
        model = Some(m);
        Ok(())
    })?;
    let rays = (!counted.is_empty()).then(|| counted.iter().sum::<f64>() / counted.len() as f64);
    let mut m = model.ok_or_else(|| anyhow::anyhow!("model"))?;
    let pipelined = if first_param_on_flex(&m) {
        None
    } else {
        let t = Instant::now();
        for _ in 0..steps.max(1) {
            m = stepper.step_unread(task, m)?.0;
        }
        sync(&m);
        Some(t.elapsed().as_secs_f64() * 1e3 / steps.max(1) as f64)
    };
    Ok(Timing {
        times,
        rays,
        pipelined,
    })
}

/// Whether the model's first parameter lives on flex, where reading back costs nothing.
fn first_param_on_flex<M: Module>(model: &M) -> bool {
    first_param(model).is_none_or(|p| ins_core::kernels::flex::on_flex(&p))
}
