//! Frozen kernels kept in their GEMM layout between calls.
//!
//! VGG is frozen, yet each stylization step packed its weights to BF16 for the forward and
//! flipped and packed them again for the input gradient: about a twentieth of a `siren` step.
//! An entry holds a clone of the weight tensor, so its storage can neither be freed (and its
//! address reused) nor written in place (Flex copies shared storage before it writes): the same
//! storage with the same layout holds the same values, and a hit is never stale.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use burn::backend::flex::FlexTensor;

use crate::engine::Engine;
use crate::kernel_matrix::KernelMatrix;

/// Which product a kernel matrix feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// The forward: the kernel as it is.
    Forward,
    /// The input gradient: the flipped kernel with its channels swapped.
    InputGrad,
}

struct Entry {
    weight: FlexTensor,
    role: Role,
    engine: Engine,
    kernel: Arc<KernelMatrix>,
}

impl Entry {
    fn holds(&self, weight: &FlexTensor, role: Role, engine: Engine) -> bool {
        self.role == role
            && self.engine == engine
            && self.weight.dtype() == weight.dtype()
            && self.weight.layout() == weight.layout()
            && Arc::ptr_eq(&self.weight.data_arc(), &weight.data_arc())
    }
}

/// Entries kept, most recent first: VGG-16 up to relu4_3 has 10 convolutions, each with a
/// forward and an input-gradient matrix.
const CAPACITY: usize = 32;

static CACHE: Mutex<VecDeque<Entry>> = Mutex::new(VecDeque::new());
static BUILT: AtomicUsize = AtomicUsize::new(0);

fn cache() -> MutexGuard<'static, VecDeque<Entry>> {
    // A panic elsewhere while holding the lock leaves the entries themselves intact.
    CACHE
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The kernel matrix of `weight` for `role` on `engine`: a kept one, or `build()` kept.
pub fn kernel_matrix(
    weight: &FlexTensor,
    role: Role,
    engine: Engine,
    build: impl FnOnce() -> KernelMatrix,
) -> Arc<KernelMatrix> {
    {
        let mut entries = cache();
        if let Some(i) = entries.iter().position(|e| e.holds(weight, role, engine)) {
            let entry = entries.remove(i).expect("found above");
            let kernel = entry.kernel.clone();
            entries.push_front(entry);
            return kernel;
        }
    }
    // Built outside the lock: other convolutions go on meanwhile.
    let kernel = Arc::new(build());
    BUILT.fetch_add(1, Ordering::Relaxed);
    let mut entries = cache();
    entries.push_front(Entry {
        weight: weight.clone(),
        role,
        engine,
        kernel: kernel.clone(),
    });
    entries.truncate(CAPACITY);
    kernel
}

/// Matrices built and kept so far, in this process (for tests).
pub fn built() -> usize {
    BUILT.load(Ordering::Relaxed)
}
