//! `ins-cli bench`: the fixed workloads of BENCHMARKS.md, one JSON line each.

use std::time::Instant;

use anyhow::{Result, bail};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::Distribution;
use clap::Args;
use ins_conv::Precision;
use ins_core::backend::BackendChoice;
use ins_core::data::plain_image::pixel_coordinates;
use ins_core::loss::{StyleTarget, content_loss, mse, style_loss};
use ins_core::modules::cim::SirenCimConfig;
use ins_core::modules::field::CimKind;
use ins_core::modules::ins::Ins;
use ins_core::modules::sim::SimConfig;
use ins_core::render::geometry::Vec3;
use ins_core::render::rays::Rays;
use ins_models::nerf::NerfModel;
use ins_models::nerf::model::NerfArch;
use ins_models::nerf::render::{RenderRays, Sampling, render};
use vgg_import::Vgg16Features;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Workloads: vgg, vgg-layers (per-convolution profile), siren, nerf-pretrain, nerf-stylize,
    /// nerf-grid, hash-grid, hash-grid-reference, idr-pretrain (default: the first five of
    /// BENCHMARKS.md).
    workloads: Vec<String>,
    /// Backend.
    #[arg(long, default_value = "flex")]
    backend: BackendChoice,
    /// Timed steps (after one warm-up step); the median is reported.
    #[arg(long, default_value_t = 5)]
    steps: usize,
    /// Arithmetic of the VGG convolutions: f32, or bf16 (AMX or AVX-512 BF16; f32 where the
    /// CPU has neither). Default: bf16 where the CPU can, as in training.
    #[arg(long)]
    precision: Option<Precision>,
}

const STYLE_WEIGHT: f64 = 1e8;

pub fn run(args: BenchArgs) -> Result<()> {
    let workloads = if args.workloads.is_empty() {
        ["vgg", "siren", "nerf-pretrain", "nerf-stylize", "nerf-grid"]
            .map(String::from)
            .to_vec()
    } else {
        args.workloads.clone()
    };
    let backend = args.backend.resolve();
    let precision = args.precision.unwrap_or(Precision::Bf16.effective());
    for w in &workloads {
        let device = backend.device().autodiff();
        device.seed(42);
        if w == "vgg-layers" {
            crate::bench_vgg_layers::run(&device, &backend.to_string(), args.steps, precision)?;
            continue;
        }
        let times = match w.as_str() {
            "vgg" => bench_vgg(&device, args.steps, precision)?,
            "siren" => bench_siren(&device, args.steps, precision)?,
            "nerf-pretrain" => bench_nerf_pretrain(&device, args.steps)?,
            "nerf-stylize" => bench_nerf_stylize(&device, args.steps, precision)?,
            "nerf-grid" => bench_nerf_grid(&device, args.steps)?,
            "hash-grid" => bench_hash_grid(&device, args.steps, true)?,
            "hash-grid-reference" => bench_hash_grid(&device, args.steps, false)?,
            "idr-pretrain" => crate::bench_idr::bench_idr_pretrain(&device, args.steps)?,
            other => bail!(
                "unknown workload {other:?} (known: vgg, vgg-layers, siren, nerf-pretrain, nerf-stylize, nerf-grid, hash-grid, hash-grid-reference, idr-pretrain)"
            ),
        };
        let mut sorted = times.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let median = sorted[sorted.len() / 2];
        let mut line = serde_json::json!({
            "workload": w,
            "backend": backend.to_string(),
            "ms_per_step": (median * 10.0).round() / 10.0,
            "steps": times.len(),
            "min_ms": (sorted[0] * 10.0).round() / 10.0,
            "max_ms": (sorted[sorted.len() - 1] * 10.0).round() / 10.0,
            "peak_rss_mb": peak_rss_mb(),
        });
        if matches!(w.as_str(), "vgg" | "siren" | "nerf-stylize") {
            line["precision"] = precision.effective().to_string().into();
        }
        if let Some(rays) = rays_per_step(w) {
            line["rays_per_s"] = ((rays as f64 / median * 1e3).round()).into();
        }
        println!("{line}");
    }
    Ok(())
}

/// Rays per step of the NeRF workloads.
fn rays_per_step(w: &str) -> Option<usize> {
    match w {
        "nerf-pretrain" | "nerf-stylize" => Some(1024),
        "nerf-grid" => Some(GRID_RAYS),
        "hash-grid" | "hash-grid-reference" => Some(GRID_POINTS),
        "idr-pretrain" => Some(crate::bench_idr::rays()),
        _ => None,
    }
}

/// Peak resident memory of this process (Linux), in MiB.
fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some((kb / 1024.0).round())
}

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

fn bench_vgg(device: &Device, steps: usize, precision: Precision) -> Result<Vec<f64>> {
    let vgg = Vgg16Features::random(device).with_precision(precision);
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

fn bench_siren(device: &Device, steps: usize, precision: Precision) -> Result<Vec<f64>> {
    let vgg = Vgg16Features::random(device).with_precision(precision);
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
    let mut adam = ins_core::train::adam();
    timed(steps, || {
        let m = model.take().expect("model");
        let rgb = m.forward(coords.clone(), code.clone());
        let img = rgb.reshape([1, side, side, 3]).permute([0, 3, 1, 2]);
        let f = vgg.forward(img);
        let loss = style_loss(&f, &targets).mul_scalar(STYLE_WEIGHT) + content_loss(&f, &content);
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        let m = adam.step(1e-4, m, grads);
        let _ = m.am.gamma.val().into_scalar::<f32>();
        model = Some(m);
        Ok(())
    })
}

/// BENCHMARKS.md's rays: origins near (0, 0, 4), directions near −z, depth range [2, 6].
fn bench_rays(n: usize, seed: u64) -> RenderRays {
    use rand::SeedableRng;
    use rand_distr_free::normal;
    let mut rng = rand::rngs::SmallRng::seed_from_u64(seed);
    let mut rays = Rays::default();
    for _ in 0..n {
        let o = Vec3::new(
            0.1 * normal(&mut rng),
            0.1 * normal(&mut rng),
            4.0 + 0.1 * normal(&mut rng),
        );
        let d = Vec3::new(
            0.2 * normal(&mut rng),
            0.2 * normal(&mut rng),
            -1.0 + 0.2 * normal(&mut rng),
        )
        .normalize();
        rays.push(o, d, 2.0, 6.0);
    }
    RenderRays {
        view_dirs: rays.directions.clone(),
        rays,
    }
}

/// Standard normal draws without another dependency (Box–Muller).
mod rand_distr_free {
    use rand::Rng;
    pub fn normal(rng: &mut impl Rng) -> f32 {
        let u1: f32 = rng.random::<f32>().max(1e-12);
        let u2: f32 = rng.random();
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }
}

fn mlp_arch() -> NerfArch {
    NerfArch {
        cim: CimKind::Mlp,
        log2_table: 17,
        max_resolution: 1024,
    }
}

const BOX: [f32; 6] = [-1.5, -1.5, -1.5, 1.5, 1.5, 1.5];

fn bench_nerf_pretrain(device: &Device, steps: usize) -> Result<Vec<f64>> {
    let mut model = Some(NerfModel::new(&mlp_arch(), BOX, device));
    let rays = bench_rays(1024, 1);
    let target = Tensor::<2>::random([1024, 3], Distribution::Uniform(0.0, 1.0), device);
    let mut adam = ins_core::train::adam();
    let sampling = Sampling::CoarseFine {
        coarse: 64,
        fine: 64,
    };
    let mut seed = 0;
    timed(steps, || {
        let m = model.take().expect("model");
        seed += 1;
        let r = render(&m, &rays, sampling, None, [0.0; 3], Some(seed), device);
        let loss = mse(r.fine.rgb, target.clone())
            + mse(r.coarse_rgb.expect("coarse render"), target.clone());
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        let m = adam.step(5e-4, m, grads);
        let _ = m
            .field
            .color
            .mlp
            .rgb
            .weight
            .val()
            .slice([0..1, 0..1])
            .into_scalar::<f32>();
        model = Some(m);
        Ok(())
    })
}

fn bench_nerf_stylize(device: &Device, steps: usize, precision: Precision) -> Result<Vec<f64>> {
    let vgg = Vgg16Features::random(device).with_precision(precision);
    let tf = vgg.forward(Tensor::<4>::random(
        [1, 3, 256, 256],
        Distribution::Uniform(0.0, 1.0),
        device,
    ));
    let targets = StyleTarget::from_features(&tf).grams;
    let content = vgg
        .forward(Tensor::<4>::random(
            [1, 3, 32, 32],
            Distribution::Uniform(0.0, 1.0),
            device,
        ))
        .relu2_2
        .detach();
    let base = NerfModel::new(&mlp_arch(), BOX, device);
    let teacher = base.field.geometry.clone().no_grad();
    let mut m0 = base.with_stylizer(2, 256, 10, device);
    m0.coarse = m0.coarse.map(|c| c.no_grad());
    let mut model = Some(m0);
    let rays = bench_rays(1024, 2);
    let code = Tensor::<2>::from_floats([[1.0, 0.0]], device);
    let mut adam = ins_core::train::adam();
    let sampling = Sampling::CoarseFine {
        coarse: 64,
        fine: 64,
    };
    let mut seed = 0;
    timed(steps, || {
        let m = model.take().expect("model");
        seed += 1;
        let r = render(
            &m,
            &rays,
            sampling,
            Some(code.clone()),
            [0.0; 3],
            Some(seed),
            device,
        );
        let img = r.fine.rgb.reshape([1, 32, 32, 3]).permute([0, 3, 1, 2]);
        let f = vgg.forward(img);
        let (teacher_raw, _) = teacher.forward(r.points.detach());
        let [s, n] = r.raw.dims();
        let geo = (r.raw - teacher_raw.detach().reshape([1, n]).expand([s, n]))
            .abs()
            .mean();
        let loss = style_loss(&f, &targets).mul_scalar(STYLE_WEIGHT)
            + content_loss(&f, &content)
            + geo.mul_scalar(1e6);
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        let m = adam.step(5e-4, m, grads);
        let _ = m
            .field
            .color
            .mlp
            .rgb
            .weight
            .val()
            .slice([0..1, 0..1])
            .into_scalar::<f32>();
        model = Some(m);
        Ok(())
    })
}

/// Rays of a `nerf-grid` step.
const GRID_RAYS: usize = 4096;

/// A grid pretraining step: 4096 random rays through an occupancy grid whose occupied region is
/// a ball of radius 0.8 (about the share of space a lego-like object fills), photometric MSE,
/// backward, Adam.
fn bench_nerf_grid(device: &Device, steps: usize) -> Result<Vec<f64>> {
    let arch = NerfArch {
        cim: CimKind::Grid,
        log2_table: 17,
        max_resolution: 1024,
    };
    let mut model = Some(NerfModel::new(&arch, BOX, device));
    let mut grid = ins_models::nerf::run::fresh_grid(BOX, 128);
    grid.update(usize::MAX, 1, |p| {
        p.chunks_exact(3)
            .map(|q| {
                if Vec3::new(q[0], q[1], q[2]).length() < 0.8 {
                    100.0
                } else {
                    0.0
                }
            })
            .collect()
    });
    let rays = bench_rays(GRID_RAYS, 3);
    let target = Tensor::<2>::random([GRID_RAYS, 3], Distribution::Uniform(0.0, 1.0), device);
    let mut adam = ins_core::train::adam();
    let mut seed = 0;
    timed(steps, || {
        let m = model.take().expect("model");
        seed += 1;
        let sampling = Sampling::Occupancy {
            grid: &grid,
            max_per_ray: 512,
        };
        let verbose = std::env::var_os("INS_BENCH_VERBOSE").is_some();
        let t0 = Instant::now();
        let r = render(&m, &rays, sampling, None, [1.0; 3], Some(seed), device);
        let loss = mse(r.fine.rgb, target.clone());
        if verbose {
            let _ = loss.clone().into_scalar::<f32>();
        }
        let t1 = Instant::now();
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        let t2 = Instant::now();
        let m = adam.step(1e-2, m, grads);
        if verbose {
            let _ = m
                .field
                .color
                .mlp
                .rgb
                .weight
                .val()
                .slice([0..1, 0..1])
                .into_scalar::<f32>();
            eprintln!(
                "samples {} forward {:?} backward {:?} adam {:?}",
                r.samples,
                t1 - t0,
                t2 - t1,
                t2.elapsed()
            );
        }
        let _ = m
            .field
            .color
            .mlp
            .rgb
            .weight
            .val()
            .slice([0..1, 0..1])
            .into_scalar::<f32>();
        model = Some(m);
        Ok(())
    })
}

/// Points of a `hash-grid` step.
const GRID_POINTS: usize = 1 << 17;

/// The hash encoding alone (16 levels × 2 features, T = 2^17, resolutions 16…1024) of 2^17
/// random points, forward and backward to the table: through the kernel op (`kernel`) or the
/// plain Burn-ops reference.
fn bench_hash_grid(device: &Device, steps: usize, kernel: bool) -> Result<Vec<f64>> {
    use ins_core::modules::hash_grid::{HashGridConfig, op, reference};
    let grid = HashGridConfig::new().init(device);
    let x = Tensor::<2>::random([GRID_POINTS, 3], Distribution::Uniform(0.0, 1.0), device);
    let g = Tensor::<2>::random([GRID_POINTS, grid.d_out()], Distribution::Default, device);
    if kernel && !op::kernel_device(device) {
        bail!("the hash-grid kernel runs on flex and ndarray only (this is {device:?})");
    }
    timed(steps, || {
        let t = grid.table.val();
        let enc = if kernel {
            op::encode_kernel(x.clone(), t.clone(), grid.shape)
        } else {
            reference::encode(x.clone(), t.clone(), grid.shape)
        };
        let grads = (enc * g.clone()).sum().backward();
        let gt = t
            .grad(&grads)
            .ok_or_else(|| anyhow::anyhow!("no table gradient"))?;
        let _ = gt.slice([0..1, 0..1]).into_scalar::<f32>();
        Ok(())
    })
}
