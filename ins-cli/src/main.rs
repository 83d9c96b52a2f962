//! `ins-cli`: train, render, inspect VGG, check data and benchmark stylized implicit neural
//! representations.

mod bench;
mod common;
mod consistency_cmd;
mod counter;
mod data_cmd;
mod eval_mesh_cmd;
mod export_cmd;
mod idr_cmd;
mod nerf_cmd;
mod report_cmd;
mod sfm_cmd;
mod siren_cmd;
mod stages;
mod stylize2d_cmd;
mod stylize_cmd;
mod stylize_inputs;
mod vgg_cmd;
mod view_cmd;
mod view_size;
mod viewer;

use clap::{ArgMatches, CommandFactory, FromArgMatches, Parser, Subcommand};

/// mimalloc keeps freed pages for reuse: training steps allocate and free the same large
/// tensors every step, and the system allocator returned them to the OS each time (a tenth of
/// a NeRF step went to page faults).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Stylized implicit neural representations (INS, ECCV 2022) on Burn.
#[derive(Parser, Debug)]
#[command(name = "ins-cli", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// From a folder of photos and a painting to a video, a report and a mesh, in one command
    /// (poses, pretraining, stylizing, outputs); run it again to continue where it stopped.
    Stylize(stylize_cmd::Stylize),
    /// Train a stylized representation.
    Train {
        #[command(subcommand)]
        variant: TrainVariant,
    },
    /// Render a trained representation.
    Render {
        #[command(subcommand)]
        variant: RenderVariant,
    },
    /// Evaluate a trained representation.
    Eval {
        #[command(subcommand)]
        variant: EvalVariant,
    },
    /// Look around a run in the browser: orbit, zoom, style sliders, depth and normals.
    View(view_cmd::View),
    /// Export a trained representation (meshes of surfaces).
    Export {
        #[command(subcommand)]
        command: ExportCommand,
    },
    /// VGG-16 weights: fetch, inspect, extract features.
    Vgg {
        #[command(subcommand)]
        command: vgg_cmd::VggCommand,
    },
    /// Datasets: check a scene, print rays, write synthetic scenes.
    Data {
        #[command(subcommand)]
        command: data_cmd::DataCommand,
    },
    /// Classic 2D style transfer (Gatys) of an image, or of each frame of a folder on its own.
    Stylize2d(stylize2d_cmd::Stylize2d),
    /// A static HTML report of a stylized NeRF or IDR run: views, animations, depth, loss curves,
    /// consistency and style tables (runs `eval consistency` first if needed).
    Report(report_cmd::Report),
    /// Benchmark workloads of docs/benchmarks.md (one JSON line each).
    Bench(bench::BenchArgs),
}

#[derive(Subcommand, Debug)]
enum TrainVariant {
    /// SIREN + INS: fit an image, then stylize it (one or several styles).
    Siren(siren_cmd::TrainSiren),
    /// NeRF + INS: pretrain a radiance field on a scene (--scene), or stylize one (--from).
    Nerf(nerf_cmd::TrainNerf),
    /// IDR + INS: reconstruct a surface from masked views (--scene), or stylize one (--from).
    Idr(idr_cmd::TrainIdr),
}

#[derive(Subcommand, Debug)]
enum RenderVariant {
    /// Render a SIREN + INS run at any size and style mix.
    Siren(siren_cmd::RenderSiren),
    /// Render views, a split or a camera path of a NeRF run (PNG, folder, GIF, MP4).
    Nerf(nerf_cmd::RenderNerf),
    /// Render a view or a turntable of an IDR run (colour or shaded normals).
    Idr(idr_cmd::RenderIdr),
}

#[derive(Subcommand, Debug)]
enum EvalVariant {
    /// PSNR and SSIM on held-out views; depth and opacity against the teacher for stylized runs.
    Nerf(nerf_cmd::EvalNerf),
    /// Silhouette IoU and PSNR inside the mask on the held-out views of an IDR run.
    Idr(idr_cmd::EvalIdr),
    /// View consistency of a stylized NeRF or IDR run along a path (frames warped by the pretrained
    /// depth), against the per-view 2D baseline; Gram and content distances per view; the
    /// painting's texture on the object against Gatys run to convergence.
    Consistency(consistency_cmd::EvalConsistency),
    /// A NeRF or IDR run's mesh against a reference surface (DTU's ground-truth points, a
    /// synthesized scene's): accuracy, completeness, Chamfer distance, F-score.
    Mesh(eval_mesh_cmd::EvalMesh),
}

#[derive(Subcommand, Debug)]
enum ExportCommand {
    /// Marching cubes of a NeRF or IDR run's surface, vertex-coloured, as PLY or glTF (.glb).
    Mesh(export_cmd::ExportMesh),
}

/// The matches of `train <variant>`, where a variant's flags live (to tell flags given on the
/// command line from defaults when merging a `--config` file).
fn variant_matches<'a>(m: &'a ArgMatches, command: &str) -> &'a ArgMatches {
    m.subcommand_matches(command)
        .and_then(|t| t.subcommand().map(|(_, v)| v))
        .unwrap_or(m)
}

fn run(cli: Cli, matches: &ArgMatches) -> anyhow::Result<()> {
    match cli.command {
        Command::Train { variant } => {
            let m = variant_matches(matches, "train");
            match variant {
                TrainVariant::Siren(a) => siren_cmd::train(a, m),
                TrainVariant::Nerf(a) => nerf_cmd::train(a, m),
                TrainVariant::Idr(a) => idr_cmd::train(a, m),
            }
        }
        Command::Render { variant } => match variant {
            RenderVariant::Siren(a) => siren_cmd::render(a),
            RenderVariant::Nerf(a) => nerf_cmd::render(a),
            RenderVariant::Idr(a) => idr_cmd::render(a),
        },
        Command::Eval { variant } => match variant {
            EvalVariant::Nerf(a) => nerf_cmd::eval(a),
            EvalVariant::Idr(a) => idr_cmd::eval(a),
            EvalVariant::Consistency(a) => consistency_cmd::run(a),
            EvalVariant::Mesh(a) => eval_mesh_cmd::run(a),
        },
        Command::Stylize(a) => stylize_cmd::run(a),
        Command::View(a) => view_cmd::run(a),
        Command::Export { command } => match command {
            ExportCommand::Mesh(a) => export_cmd::run(a),
        },
        Command::Vgg { command } => vgg_cmd::run(command),
        Command::Data { command } => data_cmd::run(command),
        Command::Stylize2d(a) => stylize2d_cmd::run(a),
        Command::Report(a) => report_cmd::run(a),
        Command::Bench(args) => bench::run(args),
    }
}

/// mimalloc's `purge_delay` option (`mi_option_t` 15; the sys crate names no constant for it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

fn main() {
    // Never hand freed memory back to the OS: the next step needs the same amount again.
    // SAFETY: plain option setter of the allocator, called before any thread exists.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    let matches = Cli::command().get_matches();
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(c) => c,
        Err(e) => e.exit(),
    };
    // Probing for a GPU loads Vulkan drivers whose window-system part complains on stderr when
    // a headless machine has no XDG_RUNTIME_DIR; give it a harmless one. Done first, while the
    // program is still single-threaded.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        // SAFETY: no other thread exists yet.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
    }
    // Errors are reported as one message naming the problem; an internal panic is reported
    // the same way rather than as a backtrace. With RUST_BACKTRACE set, both also print where
    // they came from.
    let backtrace = std::env::var_os("RUST_BACKTRACE").is_some_and(|v| v != "0");
    std::panic::set_hook(Box::new(move |info| {
        if ins_core::contain::is_contained() {
            return; // a decoder's panic on damaged input, reported as an error naming the file
        }
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| info.payload().downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "unknown panic".into());
        let at = info
            .location()
            .map(|l| format!(" (at {}:{})", l.file(), l.line()))
            .unwrap_or_default();
        if let Some(failure) = ins_core::gpu_failure::memory_failure(&msg) {
            // The failure surfaces on every thread that reads the failed work: say it once.
            static TOLD: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
            if !TOLD.swap(true, std::sync::atomic::Ordering::SeqCst) {
                let gpu = ins_core::gpu::prepared().map(|r| r.describe());
                eprintln!(
                    "error: {}",
                    ins_core::gpu_failure::memory_advice(gpu.as_deref(), failure)
                );
            }
            if !backtrace {
                return;
            }
        }
        eprintln!("error: internal failure: {msg}{at}");
        if backtrace {
            eprintln!("{}", std::backtrace::Backtrace::force_capture());
        }
    }));
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(cli, &matches))) {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            eprintln!("error: {e:#}");
            if backtrace {
                eprintln!("{}", e.backtrace());
            }
            exit_now(1);
        }
        Err(_) => exit_now(101),
    }
}

/// Ends the process with `code` without running the C library's exit handlers. Why: on an
/// NVIDIA H100 (Vulkan driver 580), a run that stopped on an error after the wgpu device was
/// up ended in a segmentation fault (status 139, after its message) while the driver's
/// handlers tore the device down under CubeCL's device thread. Everything a run writes is
/// written atomically before this point, so there is nothing left to flush but stdio.
fn exit_now(code: i32) -> ! {
    use std::io::Write;
    let _ = std::io::stdout().flush();
    let _ = std::io::stderr().flush();
    // SAFETY: `_exit` takes no pointers and never returns.
    unsafe { libc::_exit(code) }
}
