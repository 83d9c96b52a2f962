//! The CUDA backend's runtime (`--backend cuda`): Burn's CubeCL runtime on NVIDIA's driver, its
//! kernels (Burn's and this project's) compiled as CUDA C++ by NVRTC, matmuls on tensor cores.
//!
//! Why it is set up here: the driver (`libcuda`) and NVRTC are loaded at run time, so the program
//! builds and starts on machines without CUDA; but CubeCL panics deep inside on a missing
//! library, and `expect`s CUDA's headers (for NVRTC) only when it compiles its first kernel. Each
//! piece is looked for before the first tensor, and a missing one stops the run at once with a
//! message that names it and says what to do. The settings (kernel and tuning cache, tuning
//! level) are the wgpu runtime's ([`crate::gpu::configure`]).

use std::path::Path;

use burn::prelude::*;

use crate::gpu::{Adapter, AdapterKind, GpuError, GpuRuntime, RuntimeOnce, configure};

static RUNTIME: RuntimeOnce = RuntimeOnce::new();

/// Sets up the CUDA runtime once per process (later calls return the first answer): checks the
/// driver, a GPU, NVRTC and CUDA's headers, gives CubeCL its settings, and runs one small
/// kernel so that a GPU or NVRTC that refuses fails here, with its reason.
pub fn prepare(cache: &Path) -> Result<&'static GpuRuntime, GpuError> {
    RUNTIME.get_or_start(|| start(cache))
}

/// The runtime set up by [`prepare`], if it was.
pub fn prepared() -> Option<&'static GpuRuntime> {
    RUNTIME.ready()
}

/// The first CUDA device, after [`prepare`].
pub fn device(cache: &Path) -> Result<Device, GpuError> {
    prepare(cache)?;
    Ok(Device::cuda(0))
}

fn error(message: impl Into<String>) -> GpuError {
    GpuError::Cuda {
        message: message.into(),
    }
}

/// How `scripts/cuda_standin`'s stand-in for the driver names its device: it compiles every
/// kernel through the real NVRTC and runs none (`scripts/cuda_compile_check.sh`), so the first
/// kernel's sum is not checked on it.
const STANDIN_DRIVER: &str = "INS-rs CUDA stand-in";

/// Where the other backends are, for every message.
const WAYS_OUT: &str = "or run with --backend wgpu (Vulkan) or --backend flex (the CPU)";

fn start(cache: &Path) -> Result<GpuRuntime, GpuError> {
    crate::gpu::device_handle()?;
    let name = gpu_name()?;
    headers()?;
    // SAFETY: loads the NVRTC library by its usual names, and drops it.
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return Err(error(format!(
            "NVRTC (libnvrtc.so), which compiles the kernels, was not found: install the CUDA \
             toolkit or put its lib64 folder on LD_LIBRARY_PATH, {WAYS_OUT}"
        )));
    }
    let (cache, user_config, tuning) = configure(AdapterKind::Hardware, cache);
    // One small sum: the first kernel NVRTC compiles and the GPU runs. CubeCL panics on
    // failure; the panic is this backend's error here, not the run's.
    let first = std::panic::catch_unwind(|| {
        let device = Device::cuda(0);
        Tensor::<1>::from_floats([1.0, 2.0, 3.0], &device)
            .sum()
            .into_scalar::<f32>()
    });
    match first {
        Ok(6.0) => {}
        // The compile-only stand-in driver runs no kernel: its sum means nothing.
        Ok(_) if name.starts_with(STANDIN_DRIVER) => {}
        Ok(v) => {
            return Err(error(format!(
                "a first kernel on {name} summed 1 + 2 + 3 to {v}, {WAYS_OUT}"
            )));
        }
        Err(panic) => {
            let why = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown failure".into());
            return Err(error(format!(
                "{name} did not run a first kernel: {}; {WAYS_OUT}",
                why.lines().next().unwrap_or("")
            )));
        }
    }
    Ok(GpuRuntime {
        backend: "cuda",
        adapter: Adapter {
            name,
            api: "CUDA, kernels by NVRTC".into(),
            kind: AdapterKind::Hardware,
        },
        cache,
        user_config,
        tuning,
    })
}

/// The first GPU's name, from the driver.
fn gpu_name() -> Result<String, GpuError> {
    // SAFETY: loads the driver library by its usual names, and drops it.
    if !unsafe { cudarc::driver::sys::is_culib_present() } {
        return Err(error(format!(
            "no NVIDIA driver (libcuda.so) on this machine: install the GPU's driver, {WAYS_OUT}"
        )));
    }
    use cudarc::driver::result;
    let fail = |what: &str, e: cudarc::driver::DriverError| {
        error(format!("the NVIDIA driver {what}: {e}; {WAYS_OUT}"))
    };
    result::init().map_err(|e| fail("did not start", e))?;
    let count = result::device::get_count().map_err(|e| fail("counted no GPU", e))?;
    if count < 1 {
        return Err(error(format!("the NVIDIA driver sees no GPU, {WAYS_OUT}")));
    }
    let dev = result::device::get(0).map_err(|e| fail("did not open GPU 0", e))?;
    result::device::get_name(dev).map_err(|e| fail("did not name GPU 0", e))
}

/// Whether CUDA's headers, which NVRTC compiles the kernels against, are where CubeCL looks:
/// `$CUDA_PATH/include`, or under `/usr/local/cuda`, `/opt/cuda`, `/usr`.
fn headers() -> Result<(), GpuError> {
    let Some(root) = cubecl::cuda::install::cuda_path() else {
        return Err(error(format!(
            "CUDA's headers were not found (CUDA_PATH is unset and there is no /usr/local/cuda): \
             NVRTC compiles the kernels against them; install the CUDA toolkit or set CUDA_PATH \
             to a folder whose include/ holds cuda_runtime.h, {WAYS_OUT}"
        )));
    };
    let include = root.join("include");
    match missing_header(&include) {
        None => Ok(()),
        Some(header) => Err(error(format!(
            "{} has no {}: NVRTC compiles the kernels against CUDA's headers ({}); install the \
             CUDA toolkit or set CUDA_PATH to a folder whose include/ holds them, {WAYS_OUT}",
            include.display(),
            header.path,
            header.why
        ))),
    }
}

/// A header the kernels need, and why, for the message when it is missing.
struct Header {
    path: &'static str,
    /// Other places it may be (CUDA 13 keeps CCCL's headers under `include/cccl`).
    or: &'static [&'static str],
    why: &'static str,
}

/// What CubeCL's CUDA C++ includes. A machine with PyTorch's NVIDIA wheels and no toolkit has
/// the first and third, but not `crt/mma.h`, which the tensor-core matmuls' `<mma.h>` includes:
/// found with the offline compile check (`scripts/cuda_compile_check.sh`), where every such
/// kernel failed to compile without it.
const HEADERS: [Header; 3] = [
    Header {
        path: "cuda_runtime.h",
        or: &[],
        why: "the CUDA runtime's; in PyTorch's wheels, nvidia-cuda-runtime",
    },
    Header {
        path: "crt/mma.h",
        or: &[],
        why: "which the tensor-core matmuls include; in CUDA 13's wheels, nvidia-cuda-crt, \
              which PyTorch does not install",
    },
    Header {
        path: "cuda/barrier",
        or: &["cccl/cuda/barrier"],
        why: "CCCL's; in PyTorch's wheels, nvidia-cuda-cccl",
    },
];

/// The first header the kernels need that `include` lacks.
fn missing_header(include: &Path) -> Option<&'static Header> {
    HEADERS.iter().find(|h| {
        !std::iter::once(h.path)
            .chain(h.or.iter().copied())
            .any(|p| include.join(p).is_file())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_header_the_kernels_need_is_looked_for_in_turn() {
        let dir = tempfile::tempdir().unwrap();
        let inc = dir.path();
        let add = |p: &str| {
            let f = inc.join(p);
            std::fs::create_dir_all(f.parent().unwrap()).unwrap();
            std::fs::write(f, "").unwrap();
        };
        assert_eq!(missing_header(inc).map(|h| h.path), Some("cuda_runtime.h"));
        add("cuda_runtime.h");
        // PyTorch's wheels stop here: the tensor-core matmuls would not compile.
        assert_eq!(missing_header(inc).map(|h| h.path), Some("crt/mma.h"));
        add("crt/mma.h");
        assert_eq!(missing_header(inc).map(|h| h.path), Some("cuda/barrier"));
        add("cccl/cuda/barrier"); // CUDA 13's place for it
        assert!(missing_header(inc).is_none());
    }

    /// The patched `cubecl-runtime` (third_party/cubecl-runtime-0.11.3/PATCHED.md): autotune's
    /// candidates are prepared (launches dropped, kernels compiling on CUDA's workers) only
    /// where a server compiles in the background, and a tuner nested in a prepared candidate
    /// still measures for real, since the innermost guard decides.
    #[test]
    fn autotune_prepares_candidates_where_kernels_compile_in_the_background() {
        use cubecl::dry_run::{LaunchMode, Prepare, RealRun, background_compilation, launch_mode};
        // No CUDA server here: wgpu and flex compile nothing in the background.
        assert!(!background_compilation());
        assert_eq!(launch_mode(), LaunchMode::Execute);
        let measuring = RealRun::new();
        {
            let _prepared = Prepare::new();
            assert_eq!(launch_mode(), LaunchMode::Prepare);
            assert!(
                launch_mode().is_skipped(),
                "a server unaware of it drops the launch"
            );
            {
                let _nested_tuner = RealRun::new();
                assert_eq!(launch_mode(), LaunchMode::Execute);
            }
            assert_eq!(launch_mode(), LaunchMode::Prepare);
        }
        assert_eq!(launch_mode(), LaunchMode::Execute);
        drop(measuring);
    }
}
