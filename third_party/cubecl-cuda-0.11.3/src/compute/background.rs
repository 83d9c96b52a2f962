//! INS-rs patch (PATCHED.md): kernels compiled on worker threads, all cores at once.
//!
//! CubeCL compiles a kernel when it is first launched, in the thread that launches it, so a
//! cold start compiles autotune's candidates one after another: a tensor-core matmul takes
//! NVRTC about 0.4 s, and a cold run compiles hundreds of them. Autotune now issues a batch's
//! candidates once each under [`LaunchMode::Prepare`](cubecl_server::dry_run::LaunchMode)
//! before measuring the first (the patched `cubecl-runtime`); each such launch of a kernel
//! not compiled yet starts its compilation here (CubeCL's code generation and NVRTC, nothing
//! that touches the device) and returns. The measured launch that follows takes the result,
//! waiting for it if need be, and loads the module in the server's thread as before. The PTX
//! is what the synchronous path gives for the same source: NVRTC may be called from several
//! threads at once.
//!
//! `CUBECL_BACKGROUND_COMPILE=0` turns it off; with one core it is off (nothing to overlap).

use crate::compiler::{CudaCompilationOptions, CudaCompiler, CudaRepresentation};
use cubecl_core::prelude::KernelId;
use cubecl_server::compiler::CompilationError;
use cubecl_server::kernel::{CompiledKernel, CubeKernel};
use std::collections::HashMap;
use std::ffi::c_char;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};

/// A kernel compiled on a worker: what the server's thread needs to load it.
pub(crate) struct Compiled {
    pub jitc: CompiledKernel<CudaCompiler>,
    pub ptx: Vec<c_char>,
}

/// One kernel to compile, and where its result goes.
struct Job {
    kernel: Box<dyn CubeKernel>,
    options: CudaCompilationOptions,
    arch_option: String,
    done: Sender<Option<Compiled>>,
}

/// The workers' queue and the compilations started and not yet taken.
#[derive(Default)]
pub(crate) struct BackgroundCompiler {
    queue: Option<Sender<Job>>,
    pending: HashMap<KernelId, Receiver<Option<Compiled>>>,
}

impl core::fmt::Debug for BackgroundCompiler {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("BackgroundCompiler")
            .field("enabled", &self.queue.is_some())
            .field("pending", &self.pending.len())
            .finish()
    }
}

impl BackgroundCompiler {
    /// Workers on every core, unless `CUBECL_BACKGROUND_COMPILE=0` or there is one core. Tells
    /// autotune whether to prepare its candidates.
    pub fn new() -> Self {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let wanted = std::env::var("CUBECL_BACKGROUND_COMPILE").map_or(true, |v| v != "0");
        let enabled = wanted && cores > 1;
        cubecl_server::dry_run::set_background_compilation(enabled);
        if !enabled {
            return Self::default();
        }
        let (queue, jobs) = channel::<Job>();
        let jobs = Arc::new(Mutex::new(jobs));
        for i in 0..cores {
            let jobs = jobs.clone();
            let spawned = std::thread::Builder::new()
                .name(format!("cubecl-compile-{i}"))
                .spawn(move || work(jobs));
            if spawned.is_err() {
                cubecl_server::dry_run::set_background_compilation(false);
                return Self::default();
            }
        }
        Self {
            queue: Some(queue),
            pending: HashMap::new(),
        }
    }

    /// Whether kernels can be handed to the workers.
    pub fn enabled(&self) -> bool {
        self.queue.is_some()
    }

    /// Whether `kernel_id` was handed to the workers and not yet taken.
    pub fn is_pending(&self, kernel_id: &KernelId) -> bool {
        self.pending.contains_key(kernel_id)
    }

    /// Hands `kernel` to the workers; gives it back if they are gone.
    pub fn start(
        &mut self,
        kernel_id: KernelId,
        kernel: Box<dyn CubeKernel>,
        options: CudaCompilationOptions,
        arch_option: String,
    ) -> Result<(), Box<dyn CubeKernel>> {
        let Some(queue) = &self.queue else {
            return Err(kernel);
        };
        let (done, result) = channel();
        let job = Job {
            kernel,
            options,
            arch_option,
            done,
        };
        match queue.send(job) {
            Ok(()) => {
                self.pending.insert(kernel_id, result);
                Ok(())
            }
            Err(err) => Err(err.0.kernel),
        }
    }

    /// The compiled kernel, waiting for its worker if need be; `None` if it was never started
    /// or did not compile (the caller then compiles it in its own thread, which reports why).
    pub fn take(&mut self, kernel_id: &KernelId) -> Option<Compiled> {
        self.pending.remove(kernel_id)?.recv().ok().flatten()
    }
}

/// A worker: compiles jobs until the queue closes.
fn work(jobs: Arc<Mutex<Receiver<Job>>>) {
    loop {
        let job = match jobs.lock() {
            Ok(jobs) => jobs.recv(),
            Err(_) => return,
        };
        let Ok(job) = job else {
            return;
        };
        let compiled = compile(&*job.kernel, &job.options, &job.arch_option).ok();
        let _ = job.done.send(compiled);
    }
}

/// What the server's synchronous path does before loading: expand, generate CUDA C++, NVRTC.
fn compile(
    kernel: &dyn CubeKernel,
    options: &CudaCompilationOptions,
    arch_option: &str,
) -> Result<Compiled, CompilationError> {
    let definition = cubecl_core::define_kernel(kernel)?;
    let jitc = CompiledKernel::compile(kernel, definition, &mut CudaCompiler::default(), options)?;
    let Some(CudaRepresentation::Cpp(_)) = &jitc.repr else {
        return Err(CompilationError::Generic {
            reason: "only CUDA C++ compiles in the background".to_string(),
            backtrace: cubecl_environment::backtrace::BackTrace::capture(),
        });
    };
    let ptx = super::context::nvrtc_compile(arch_option, &jitc.source)?;
    Ok(Compiled { jitc, ptx })
}
