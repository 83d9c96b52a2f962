//! `ins-cli`: train, render, inspect VGG, check data and benchmark stylized implicit neural
//! representations.

mod bench;
mod data_cmd;
mod siren_cmd;
mod vgg_cmd;

use clap::{Parser, Subcommand};

/// Stylized implicit neural representations (INS, ECCV 2022) on Burn.
#[derive(Parser, Debug)]
#[command(name = "ins-cli", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Train a stylized representation.
    Train {
        #[command(subcommand)]
        variant: siren_cmd::TrainVariant,
    },
    /// Render a trained representation.
    Render {
        #[command(subcommand)]
        variant: siren_cmd::RenderVariant,
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
    /// Benchmark workloads of BENCHMARKS.md (one JSON line each).
    Bench(bench::BenchArgs),
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Train { variant } => siren_cmd::train(variant),
        Command::Render { variant } => siren_cmd::render(variant),
        Command::Vgg { command } => vgg_cmd::run(command),
        Command::Data { command } => data_cmd::run(command),
        Command::Bench(args) => bench::run(args),
    }
}

fn main() {
    let cli = Cli::parse();
    // Probing for a GPU loads Vulkan drivers whose window-system part complains on stderr when
    // a headless machine has no XDG_RUNTIME_DIR; give it a harmless one. Done first, while the
    // program is still single-threaded.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        // SAFETY: no other thread exists yet.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
    }
    // Errors are reported as one message naming the problem; an internal panic is reported
    // the same way rather than as a backtrace.
    std::panic::set_hook(Box::new(|info| {
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
        eprintln!("error: internal failure: {msg}{at}");
    }));
    match std::panic::catch_unwind(|| run(cli)) {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
        Err(_) => std::process::exit(101),
    }
}
