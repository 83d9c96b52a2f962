//! Choosing the compute backend at run time. Every backend runs the same code: Burn tensors
//! carry their backend in their `Device`.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

/// What `--backend ndarray` prints (once) before running on flex.
pub const NDARRAY_NOTE: &str = "--backend ndarray: Burn 0.22 replaces its ndarray backend with \
     flex, the faster CPU backend; running on flex";

/// A backend choice as given on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// wgpu when a hardware GPU adapter exists, otherwise flex.
    #[default]
    Auto,
    /// Burn's pure-Rust CPU backend (the fastest on CPU).
    Flex,
    /// wgpu (Vulkan/Metal/DX12; on CPU-only machines Mesa's lavapipe).
    Wgpu,
    /// CUDA on an NVIDIA GPU (kernels compiled by NVRTC; the driver, NVRTC and CUDA's headers
    /// found at run time).
    Cuda,
}

impl std::str::FromStr for BackendChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "flex" | "cpu" => Ok(Self::Flex),
            "wgpu" | "gpu" => Ok(Self::Wgpu),
            "cuda" => Ok(Self::Cuda),
            // The design's first name for the CPU backend. Burn 0.22 deprecates ndarray for
            // flex, and this build leaves it out (the largest crate of the build, ten minutes
            // of compiling, for a backend slower than flex): run flex and say so.
            "ndarray" => {
                static TOLD: std::sync::Once = std::sync::Once::new();
                TOLD.call_once(|| eprintln!("{NDARRAY_NOTE}"));
                Ok(Self::Flex)
            }
            _ => Err(format!(
                "unknown backend {s:?} (expected auto, flex, wgpu or cuda)"
            )),
        }
    }
}

impl std::fmt::Display for BackendChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Auto => "auto",
            Self::Flex => "flex",
            Self::Wgpu => "wgpu",
            Self::Cuda => "cuda",
        })
    }
}

impl BackendChoice {
    /// Resolves `Auto` to a concrete backend.
    pub fn resolve(self) -> Self {
        match self {
            Self::Auto => {
                if hardware_gpu_present() {
                    Self::Wgpu
                } else {
                    Self::Flex
                }
            }
            other => other,
        }
    }

    /// The device (without autodiff) for this choice; for wgpu and CUDA, after setting up
    /// their runtime ([`crate::gpu::prepare`], [`crate::cuda::prepare`], caching under
    /// `$INS_CACHE_DIR/cubecl`), so that a machine without an adapter, a driver or CUDA's
    /// compiler gets a message saying what to do.
    #[allow(deprecated)]
    pub fn try_device(self) -> Result<Device, crate::gpu::GpuError> {
        let cache = || vgg_import::source::cache_dir(None).join("cubecl");
        Ok(match self.resolve() {
            Self::Flex | Self::Auto => Device::flex(),
            Self::Wgpu => crate::gpu::device(&cache())?,
            Self::Cuda => crate::cuda::device(&cache())?,
        })
    }

    /// [`Self::try_device`] for tests and benchmarks, which stop on the message.
    pub fn device(self) -> Device {
        self.try_device().unwrap_or_else(|e| panic!("{e}"))
    }
}

/// Whether a discrete or integrated GPU (not a software rasterizer) is visible to wgpu.
/// `INS_NO_GPU=1` forces "no".
pub fn hardware_gpu_present() -> bool {
    if std::env::var_os("INS_NO_GPU").is_some() {
        return false;
    }
    // Asks wgpu without opening a device: opening one would fix CubeCL's settings before
    // `gpu::prepare` could choose them.
    matches!(
        crate::gpu::find_adapter(),
        Ok(crate::gpu::Adapter {
            kind: crate::gpu::AdapterKind::Hardware,
            ..
        })
    )
}

#[cfg(test)]
mod tests {
    use super::BackendChoice;

    #[test]
    fn names_parse_and_print_back() {
        for name in ["auto", "flex", "wgpu", "cuda"] {
            let choice: BackendChoice = name.parse().unwrap();
            assert_eq!(choice.to_string(), name);
        }
        assert_eq!("CPU".parse::<BackendChoice>(), Ok(BackendChoice::Flex));
        assert_eq!("gpu".parse::<BackendChoice>(), Ok(BackendChoice::Wgpu));
    }

    #[test]
    fn the_dropped_ndarray_backend_runs_flex() {
        assert_eq!("ndarray".parse::<BackendChoice>(), Ok(BackendChoice::Flex));
        assert!(super::NDARRAY_NOTE.contains("flex"));
        let e = "tpu".parse::<BackendChoice>().unwrap_err();
        assert!(
            e.contains("\"tpu\"") && e.contains("auto, flex, wgpu or cuda"),
            "{e}"
        );
    }
}
