//! The wgpu backend's runtime, set up once before its first tensor: which adapter it will use
//! (a clear error when there is none, instead of a panic deep in CubeCL), where CubeCL keeps
//! its compiled kernels and tuning results, and how much it tunes. The CUDA backend
//! (`cuda.rs`) takes the same settings ([`configure`]) and reports itself the same way
//! ([`GpuRuntime`]).
//!
//! Why the program chooses CubeCL's settings: by default CubeCL keeps its cache in the
//! `target/` of the outermost `Cargo.toml` above the working directory (or a user cache folder
//! when there is none), so where a user's tuning results went depended on where they stood; here
//! it lives beside the project's other caches. And on a software Vulkan (Mesa's lavapipe, the
//! only "GPU" of CPU-only machines), compiling each candidate kernel costs seconds, so tuning
//! is minimal there with one sample per candidate. A `cubecl.toml` (or `burn.toml`) the user
//! keeps in the working directory or above wins over both.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use burn::prelude::*;
use cubecl::config::autotune::{AutotuneLevel, BenchConfig};
use cubecl::config::cache::CacheConfig;
use cubecl::config::{CubeClRuntimeConfig, RuntimeConfig};
use cubecl::wgpu::wgpu;
use cubecl_common::device_handle::{DEVICE_HANDLE_VAR, DeviceHandleKind};

/// How the adapter computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdapterKind {
    /// A discrete, integrated or virtual GPU.
    Hardware,
    /// A rasterizer running on the CPU (lavapipe, llvmpipe, SwiftShader).
    Software,
}

/// The adapter a wgpu device comes up on, as wgpu reports it.
#[derive(Debug, Clone)]
pub struct Adapter {
    /// The adapter's name ("NVIDIA H100", "llvmpipe (LLVM 19.1.7, 256 bits)").
    pub name: String,
    /// The graphics API (Vulkan, Metal, Dx12, Gl).
    pub api: String,
    /// Hardware or software.
    pub kind: AdapterKind,
}

/// The settings a GPU run (wgpu or CUDA) computes with.
#[derive(Debug, Clone)]
pub struct GpuRuntime {
    /// The backend's name on the command line (`wgpu`, `cuda`).
    pub backend: &'static str,
    /// The adapter.
    pub adapter: Adapter,
    /// Where CubeCL keeps compiled kernels and autotune results (`None`: a user config decides).
    pub cache: Option<PathBuf>,
    /// The user's CubeCL config file, when one applies.
    pub user_config: Option<PathBuf>,
    /// How kernels are tuned, in words.
    pub tuning: &'static str,
}

impl GpuRuntime {
    /// What a first run on this runtime spends its first minutes on, for a progress line.
    pub fn first_steps_note(&self) -> String {
        let cache = match (&self.cache, &self.user_config) {
            (Some(c), _) => format!("kept in {}", c.display()),
            (None, Some(f)) => format!("kept where {} says", f.display()),
            (None, None) => "kept by CubeCL".into(),
        };
        let slow = match self.adapter.kind {
            AdapterKind::Software => {
                " (a software adapter: minutes the first time, and every step is slow; on \
                 Mesa's lavapipe a shader's loops also stop after 65,535 passes, so a sum over \
                 more values than that, as in a NeRF step at the default sizes, comes out \
                 short; --backend flex is faster, and exact, on this machine)"
            }
            AdapterKind::Hardware => "",
        };
        format!(
            "{}: the first steps compile and tune GPU kernels{slow}; tuning {}; results \
             {cache}, so later runs start faster",
            self.describe(),
            self.tuning
        )
    }

    /// The backend and its adapter in words ("wgpu on NVIDIA H100 (Vulkan)").
    pub fn describe(&self) -> String {
        format!(
            "{} on {} ({})",
            self.backend, self.adapter.name, self.adapter.api
        )
    }
}

/// Why the wgpu backend cannot start.
#[derive(Debug, Clone, thiserror::Error)]
pub enum GpuError {
    /// No graphics API reported an adapter.
    #[error(
        "--backend wgpu: no GPU adapter found (wgpu asked {apis}); run with --backend flex (the CPU), \
         or install the GPU's Vulkan driver (on a machine without a GPU, Mesa's lavapipe: the \
         mesa-vulkan-drivers package)"
    )]
    NoAdapter {
        /// The APIs asked.
        apis: String,
    },
    /// CUDA cannot run here (no driver, no GPU, no NVRTC or headers) or did not start.
    #[error("--backend cuda: {message}")]
    Cuda {
        /// What is missing or failed, and what to do.
        message: String,
    },
    /// `CUBECL_DEVICE_HANDLE` names no handle CubeCL has.
    #[error(
        "CUBECL_DEVICE_HANDLE={value:?} names no device handle: use `reentrant` (the default: \
         CubeCL's work in the calling thread) or `channel` (a thread per device service, \
         CubeCL's own default), or leave it unset"
    )]
    DeviceHandle {
        /// The variable's value.
        value: String,
    },
    /// The adapter is there but refused to start.
    #[error(
        "--backend wgpu: the {adapter} adapter did not start: {message}; run with --backend flex, \
         or check the GPU driver"
    )]
    Start {
        /// The adapter's name.
        adapter: String,
        /// wgpu's or CubeCL's reason.
        message: String,
    },
}

/// The graphics APIs CubeCL's automatic choice tries on this platform, in its order.
fn api_chain() -> Vec<wgpu::Backend> {
    if cfg!(target_os = "macos") {
        vec![wgpu::Backend::Metal]
    } else {
        vec![
            wgpu::Backend::Vulkan,
            wgpu::Backend::Dx12,
            wgpu::Backend::Gl,
        ]
    }
}

/// The adapter wgpu's high-performance choice takes: the first API of the chain that has one,
/// and on it a discrete GPU before an integrated, virtual or software one. Asked once per
/// process (`--backend auto` asks, then the wgpu runtime's setup).
pub fn find_adapter() -> Result<Adapter, GpuError> {
    static FOUND: OnceLock<Result<Adapter, GpuError>> = OnceLock::new();
    FOUND.get_or_init(search_adapters).clone()
}

fn search_adapters() -> Result<Adapter, GpuError> {
    let chain = api_chain();
    for api in &chain {
        if !wgpu::Instance::enabled_backend_features().contains((*api).into()) {
            continue;
        }
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: (*api).into(),
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let infos: Vec<wgpu::AdapterInfo> =
            cubecl::future::block_on(instance.enumerate_adapters((*api).into()))
                .iter()
                .map(wgpu::Adapter::get_info)
                .collect();
        let rank = |t: wgpu::DeviceType| match t {
            wgpu::DeviceType::DiscreteGpu => 0,
            wgpu::DeviceType::IntegratedGpu => 1,
            wgpu::DeviceType::VirtualGpu => 2,
            wgpu::DeviceType::Other => 3,
            wgpu::DeviceType::Cpu => 4,
        };
        if let Some(best) = infos.into_iter().min_by_key(|i| rank(i.device_type)) {
            return Ok(Adapter {
                kind: if best.device_type == wgpu::DeviceType::Cpu {
                    AdapterKind::Software
                } else {
                    AdapterKind::Hardware
                },
                name: best.name,
                api: format!("{api:?}"),
            });
        }
    }
    Err(GpuError::NoAdapter {
        apis: chain
            .iter()
            .map(|a| format!("{a:?}"))
            .collect::<Vec<_>>()
            .join(", "),
    })
}

/// The CubeCL config file that applies in `dir` (CubeCL reads the first of these it finds
/// walking up from the working directory).
fn user_config_file(dir: &Path) -> Option<PathBuf> {
    const NAMES: [&str; 4] = ["cubecl.toml", "CubeCL.toml", "burn.toml", "Burn.toml"];
    dir.ancestors()
        .flat_map(|d| NAMES.iter().map(move |n| d.join(n)))
        .find(|p| p.is_file())
}

/// The settings the program gives CubeCL for `kind`, caching under `cache`.
fn program_config(kind: AdapterKind, cache: &Path) -> (CubeClRuntimeConfig, &'static str) {
    // The environment variables CubeCL documents (CUBECL_AUTOTUNE_LEVEL, …) still apply.
    let mut cfg = CubeClRuntimeConfig::default().override_from_env();
    cfg.environment.path = CacheConfig::Directory(cache.to_path_buf());
    // Compiled kernels kept between runs (CUDA's PTX; wgpu's WGSL goes to the driver, which
    // keeps its own): without it every CUDA process compiled each kernel again with NVRTC.
    cfg.compilation.cache = true;
    let tuning = match kind {
        AdapterKind::Software => {
            if std::env::var_os("CUBECL_AUTOTUNE_LEVEL").is_none() {
                cfg.autotune.level = AutotuneLevel::Minimal;
            }
            cfg.autotune.bench = BenchConfig {
                min_samples: 1,
                max_samples: 1,
                short_circuit_samples: 1,
                ..BenchConfig::default()
            };
            "minimal, one sample per candidate (software adapter)"
        }
        AdapterKind::Hardware => "CubeCL's default (balanced)",
    };
    (cfg, tuning)
}

/// Gives CubeCL the program's settings for an adapter of `kind` (caching under `cache`) unless
/// a user's config file applies: the cache the settings name (`None` when they are not the
/// program's), the user's file, and the tuning in words.
pub(crate) fn configure(
    kind: AdapterKind,
    cache: &Path,
) -> (Option<PathBuf>, Option<PathBuf>, &'static str) {
    let user_config = std::env::current_dir()
        .ok()
        .and_then(|d| user_config_file(&d));
    if user_config.is_some() {
        return (None, user_config, "as the user's CubeCL config says");
    }
    let (cfg, tuning) = program_config(kind, cache);
    // `try_set` declines when CubeCL has read its config already (a device opened before
    // this call): its own settings then stay, which is also what the note says.
    if CubeClRuntimeConfig::try_set(cfg) {
        (Some(cache.to_path_buf()), None, tuning)
    } else {
        (
            None,
            None,
            "CubeCL's (its config was read before this run set one)",
        )
    }
}

/// CubeCL's words when a device's server is registered already.
const ALREADY_REGISTERED: &str = "Service already initialized";

/// A backend's runtime, set up once per process: the first answer, kept for later calls.
pub(crate) struct RuntimeOnce(OnceLock<Result<GpuRuntime, GpuError>>);

impl RuntimeOnce {
    pub(crate) const fn new() -> Self {
        Self(OnceLock::new())
    }

    /// The runtime `start` sets up, the first time; its first answer after.
    pub(crate) fn get_or_start(
        &'static self,
        start: impl FnOnce() -> Result<GpuRuntime, GpuError>,
    ) -> Result<&'static GpuRuntime, GpuError> {
        self.0.get_or_init(start).as_ref().map_err(Clone::clone)
    }

    /// The runtime, if it was set up.
    pub(crate) fn ready(&'static self) -> Option<&'static GpuRuntime> {
        self.0.get().and_then(|r| r.as_ref().ok())
    }
}

static RUNTIME: RuntimeOnce = RuntimeOnce::new();

/// Sets up the wgpu runtime once per process (later calls return the first answer): finds the
/// adapter, gives CubeCL its settings unless a user config applies, and starts the device so
/// that a driver that refuses fails here, with its reason.
pub fn prepare(cache: &Path) -> Result<&'static GpuRuntime, GpuError> {
    RUNTIME.get_or_start(|| start(cache))
}

/// The GPU runtime set up by [`prepare`] or [`crate::cuda::prepare`], if one was.
pub fn prepared() -> Option<&'static GpuRuntime> {
    RUNTIME.ready().or_else(crate::cuda::prepared)
}

/// How CubeCL reaches the device's services in this process (`third_party/cubecl-common-0.11.3`,
/// patched: the caller's thread unless `CUBECL_DEVICE_HANDLE=channel`), checked before the first
/// device so a mistyped value is an error, not CubeCL's default.
pub(crate) fn device_handle() -> Result<DeviceHandleKind, GpuError> {
    handle_named(std::env::var_os(DEVICE_HANDLE_VAR).as_deref())
}

/// The device handle this process uses, as `CUBECL_DEVICE_HANDLE` names it.
pub fn device_handle_name() -> &'static str {
    match DeviceHandleKind::current() {
        DeviceHandleKind::Channel => "channel",
        DeviceHandleKind::Reentrant => "reentrant",
    }
}

fn handle_named(value: Option<&std::ffi::OsStr>) -> Result<DeviceHandleKind, GpuError> {
    let Some(value) = value else {
        return Ok(DeviceHandleKind::Reentrant);
    };
    let value = value.to_string_lossy();
    DeviceHandleKind::parse(&value).ok_or_else(|| GpuError::DeviceHandle {
        value: value.into_owned(),
    })
}

fn start(cache: &Path) -> Result<GpuRuntime, GpuError> {
    device_handle()?;
    let adapter = find_adapter()?;
    let (cache, user_config, tuning) = configure(adapter.kind, cache);
    match cubecl::wgpu::try_init_setup::<cubecl::wgpu::AutoGraphicsApi>(
        &cubecl::wgpu::WgpuDevice::default(),
        Default::default(),
    ) {
        Ok(_) => {}
        // CubeCL's service registry can answer that the default device's server exists
        // already (seen once in CI, in a test process where nothing else had opened wgpu):
        // the device is then registered and usable, so that is a start, not a failure.
        Err(e) if e.to_string().contains(ALREADY_REGISTERED) => {}
        Err(e) => {
            return Err(GpuError::Start {
                adapter: adapter.name.clone(),
                message: e.to_string(),
            });
        }
    }
    Ok(GpuRuntime {
        backend: "wgpu",
        adapter,
        cache,
        user_config,
        tuning,
    })
}

/// The default wgpu device, after [`prepare`].
#[allow(deprecated)]
pub fn device(cache: &Path) -> Result<Device, GpuError> {
    prepare(cache)?;
    Ok(Device::wgpu(DeviceKind::DefaultDevice))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_user_config_file_above_the_working_directory_is_found() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("a/b");
        std::fs::create_dir_all(&inner).unwrap();
        assert_eq!(user_config_file(&inner), None);
        std::fs::write(dir.path().join("a/burn.toml"), "").unwrap();
        assert_eq!(
            user_config_file(&inner),
            Some(dir.path().join("a/burn.toml"))
        );
        std::fs::write(inner.join("cubecl.toml"), "").unwrap();
        assert_eq!(user_config_file(&inner), Some(inner.join("cubecl.toml")));
    }

    #[test]
    fn the_device_handle_is_the_callers_thread_unless_a_known_one_is_named() {
        use std::ffi::OsStr;
        let named = |v: Option<&str>| handle_named(v.map(OsStr::new));
        assert_eq!(named(None).unwrap(), DeviceHandleKind::Reentrant);
        assert_eq!(named(Some("channel")).unwrap(), DeviceHandleKind::Channel);
        assert_eq!(
            named(Some("reentrant")).unwrap(),
            DeviceHandleKind::Reentrant
        );
        let err = named(Some("threads")).unwrap_err().to_string();
        assert!(err.contains("CUBECL_DEVICE_HANDLE=\"threads\"") && err.contains("`channel`"));
    }

    #[test]
    fn software_adapters_tune_with_one_sample_and_kernels_are_kept_in_the_cache_given() {
        let cache = Path::new("/some/cache/cubecl");
        let (soft, _) = program_config(AdapterKind::Software, cache);
        if std::env::var_os("CUBECL_AUTOTUNE_LEVEL").is_none() {
            assert!(matches!(soft.autotune.level, AutotuneLevel::Minimal));
        }
        assert_eq!(soft.autotune.bench.samples(), (1, 1));
        assert!(matches!(&soft.environment.path, CacheConfig::Directory(p) if p == cache));
        let (hard, _) = program_config(AdapterKind::Hardware, cache);
        assert_eq!(
            hard.autotune.bench.samples(),
            BenchConfig::default().samples()
        );
        // Compiled kernels are kept between runs on both.
        assert!(soft.compilation.cache && hard.compilation.cache);
    }
}
