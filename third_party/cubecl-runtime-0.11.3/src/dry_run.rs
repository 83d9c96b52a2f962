//! Running a workload for the compilation and tuning it provokes, without
//! running the workload itself.
//!
//! Under a [`DryRun`] every launch is still expanded, compiled, validated and
//! cached, and is then dropped instead of reaching the device. A warm-up pass
//! then pays for compilation and tuning without also paying for the work that
//! provoked them, which is what makes producing a shippable environment
//! affordable.
//!
//! The launches autotune issues are the exception: they *are* the measurement,
//! so [`RealRun`] opts them back into executing.
//!
//! **Buffers are left as they were**, so anything read back during a dry run is
//! meaningless. It only suits a pass driven by the *shapes* it produces, which
//! is what keys the caches, and never one that branches on a computed value.
//!
//! The decision is made here, once, on the thread that issues the launch.
//! Servers receive the verdict as a [`LaunchMode`] argument rather than
//! deriving it: by the time a launch reaches a server thread, the context that
//! produced it is gone.

use cubecl_environment::sync::{AtomicBool, AtomicUsize, Ordering};

/// What a server should do with a launch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LaunchMode {
    /// Compile if needed, then run it. The normal case.
    Execute,
    /// Compile if needed, cache the artifact, and drop the launch.
    ///
    /// A server honoring this must still do everything a first launch does
    /// short of dispatching — expand, compile, validate, populate its caches —
    /// or the pass buys nothing.
    Skip,
    /// Drop the launch; a server that compiles in the background starts compiling the kernel
    /// if it has not, and does not wait for it (INS-rs patch: autotune's candidates issued
    /// once each before the first is measured, [`Prepare`]). A server that cannot treats it
    /// as [`Skip`](LaunchMode::Skip).
    Prepare,
}

impl LaunchMode {
    /// Whether the launch should be dropped rather than run.
    pub fn is_skipped(self) -> bool {
        matches!(self, LaunchMode::Skip | LaunchMode::Prepare)
    }

    /// Whether the kernel may compile in the background, the launch dropped.
    pub fn is_prepare(self) -> bool {
        matches!(self, LaunchMode::Prepare)
    }
}

/// What to do with a launch issued on this thread, right now: the innermost of this thread's
/// [`RealRun`] and [`Prepare`] guards decides; with neither open, an open [`DryRun`] skips.
pub fn launch_mode() -> LaunchMode {
    match real_run::innermost() {
        Some(real_run::Frame::Real) => LaunchMode::Execute,
        Some(real_run::Frame::Prepare) => LaunchMode::Prepare,
        None if dry_run() => LaunchMode::Skip,
        None => LaunchMode::Execute,
    }
}

/// Whether a server of this process compiles kernels in the background (INS-rs patch): set by
/// the server that does (CUDA, with more than one core), read by autotune before it issues a
/// batch's candidates for [`Prepare`]. Elsewhere preparing would only compile candidates that
/// a short circuit could have spared, one after another as before.
static BACKGROUND_COMPILATION: AtomicBool = AtomicBool::new(false);

/// Says whether a server of this process compiles kernels in the background.
pub fn set_background_compilation(on: bool) {
    BACKGROUND_COMPILATION.store(on, Ordering::Relaxed);
}

/// Whether a server of this process compiles kernels in the background.
pub fn background_compilation() -> bool {
    BACKGROUND_COMPILATION.load(Ordering::Relaxed)
}

/// How many dry runs are open in this process.
///
/// A depth rather than a flag so overlapping guards compose: a swap-and-restore
/// would let one thread's guard end a dry run another thread is still inside,
/// and leave the process dry-running forever once that one dropped in turn.
static DRY_RUN: AtomicUsize = AtomicUsize::new(0);

/// Whether launches are currently compiled and dropped rather than run.
pub fn dry_run() -> bool {
    DRY_RUN.load(Ordering::Relaxed) > 0
}

/// Makes every launch a dry run for as long as it lives, on every thread and
/// every device.
///
/// Overlapping guards compose, so a pass that opens one while another is still
/// open leaves the mode on until the last of them drops.
///
/// The flag is read on the thread issuing a launch, with relaxed ordering, so a
/// launch another thread had already begun issuing may still execute. What is
/// guaranteed is the launches issued by the thread that opened the guard, and
/// every launch issued after other threads observe it.
///
/// This is the only way in: there is deliberately no configuration file or
/// environment variable for it. A dry run left on by accident turns the rest of
/// the process into launches that quietly do nothing and read back
/// uninitialized memory, so its lifetime belongs to a scope in the code that
/// wants it, not to an ambient default nothing in the process can see.
///
/// ```no_run
/// # fn warm_up() {}
/// let _dry_run = cubecl_runtime::dry_run::DryRun::new();
/// warm_up();
/// ```
#[derive(Debug)]
pub struct DryRun {
    _private: (),
}

impl DryRun {
    /// Opens a dry run until the guard drops.
    #[allow(clippy::new_without_default, reason = "a guard is not a value")]
    pub fn new() -> Self {
        DRY_RUN.fetch_add(1, Ordering::Relaxed);
        Self { _private: () }
    }
}

impl Drop for DryRun {
    fn drop(&mut self) {
        DRY_RUN.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Makes the launches issued on this thread execute for real even inside a
/// [`DryRun`], for as long as it lives.
///
/// Autotune holds one: its launches are the measurement a dry run exists to
/// provoke, not the workload it exists to skip. Held across warm-up and samples
/// alike, since a candidate that was never warmed is a candidate measured on
/// its first, slowest run.
///
/// Thread-local, and the thread that matters is the one issuing the launches,
/// which is not always the one that asked for them: a task handed to
/// [`Client::exclusive`](crate::client::Client::exclusive) runs on
/// the device thread. The guard has to live inside that task, alongside the
/// launches it covers, not around the call that submits it.
#[derive(Debug)]
pub struct RealRun {
    _private: (),
}

impl RealRun {
    /// Opts this thread back into executing until the guard drops.
    #[allow(clippy::new_without_default, reason = "a guard is not a value")]
    pub fn new() -> Self {
        real_run::enter(real_run::Frame::Real);
        Self { _private: () }
    }
}

/// Makes the launches issued on this thread [`LaunchMode::Prepare`] for as long as it lives,
/// unless a [`RealRun`] opened inside it (a tuner nested in a candidate measures for real).
/// INS-rs patch: autotune issues a batch's candidates once each under it, so a server that
/// compiles in the background compiles the whole batch at once.
#[derive(Debug)]
pub struct Prepare {
    _private: (),
}

impl Prepare {
    /// Drops this thread's launches, compiling in the background, until the guard drops.
    #[allow(clippy::new_without_default, reason = "a guard is not a value")]
    pub fn new() -> Self {
        real_run::enter(real_run::Frame::Prepare);
        Self { _private: () }
    }
}

impl Drop for Prepare {
    fn drop(&mut self) {
        real_run::exit();
    }
}

impl Drop for RealRun {
    fn drop(&mut self) {
        real_run::exit();
    }
}

/// This thread's open [`RealRun`] and [`Prepare`] guards, innermost last (INS-rs patch: a stack
/// where CubeCL counted `RealRun`s alone, so the innermost guard decides).
mod real_run {
    /// One open guard.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub(crate) enum Frame {
        Real,
        Prepare,
    }

    #[cfg(feature = "std")]
    std::thread_local! {
        static FRAMES: core::cell::RefCell<alloc::vec::Vec<Frame>> =
            const { core::cell::RefCell::new(alloc::vec::Vec::new()) };
    }

    #[cfg(feature = "std")]
    pub(super) fn innermost() -> Option<Frame> {
        FRAMES.with(|frames| frames.borrow().last().copied())
    }

    #[cfg(test)]
    pub(super) fn depth() -> usize {
        FRAMES.with(|frames| frames.borrow().len())
    }

    #[cfg(feature = "std")]
    pub(super) fn enter(frame: Frame) {
        FRAMES.with(|frames| frames.borrow_mut().push(frame));
    }

    #[cfg(feature = "std")]
    pub(super) fn exit() {
        FRAMES.with(|frames| {
            frames.borrow_mut().pop();
        });
    }

    // No threads to be local to; this keeps the call sites uniform.
    #[cfg(not(feature = "std"))]
    pub(super) fn innermost() -> Option<Frame> {
        None
    }
    #[cfg(not(feature = "std"))]
    pub(super) fn enter(_frame: Frame) {}
    #[cfg(not(feature = "std"))]
    pub(super) fn exit() {}
}

#[cfg(test)]
mod tests {
    use super::*;
    // `serial_test`'s macro expands to `vec!`, which a `no_std` crate has to
    // bring in itself.
    use alloc::vec;

    /// The guard nests: an inner measurement ending must not cancel the outer
    /// one, or a tunable that dispatches through another tuner would have the
    /// rest of its own measurement dropped.
    #[test]
    fn real_run_nests() {
        assert_eq!(real_run::depth(), 0);
        let outer = RealRun::new();
        {
            let _inner = RealRun::new();
            assert_eq!(real_run::depth(), 2);
        }
        assert_eq!(real_run::depth(), 1, "the outer guard is still open");
        drop(outer);
        assert_eq!(real_run::depth(), 0);
    }

    /// Nothing is skipped outside a dry run, whatever the depth.
    #[test]
    #[serial_test::serial]
    fn launches_execute_by_default() {
        assert_eq!(launch_mode(), LaunchMode::Execute);
        let _real_run = RealRun::new();
        assert_eq!(launch_mode(), LaunchMode::Execute);
    }

    /// The whole contract in one place: in a dry run every launch is dropped
    /// *except* the ones a measurement issues, which are the tuning the mode
    /// exists to keep.
    #[test]
    #[serial_test::serial]
    fn a_dry_run_spares_the_measurements() {
        let _dry_run = DryRun::new();

        assert_eq!(launch_mode(), LaunchMode::Skip);
        {
            let _real_run = RealRun::new();
            assert_eq!(launch_mode(), LaunchMode::Execute, "a measurement runs");
        }
        assert_eq!(launch_mode(), LaunchMode::Skip);
    }

    /// INS-rs patch: the innermost guard decides, so a tuner nested in a prepared candidate
    /// measures for real, and the candidate's own launches are prepared again after it.
    #[test]
    #[serial_test::serial]
    fn the_innermost_guard_decides() {
        let outer = RealRun::new();
        {
            let _prepare = Prepare::new();
            assert_eq!(launch_mode(), LaunchMode::Prepare);
            assert!(launch_mode().is_skipped());
            {
                let _nested = RealRun::new();
                assert_eq!(launch_mode(), LaunchMode::Execute);
            }
            assert_eq!(launch_mode(), LaunchMode::Prepare);
        }
        assert_eq!(launch_mode(), LaunchMode::Execute);
        drop(outer);
        assert_eq!(real_run::depth(), 0);
    }

    /// Overlapping guards compose, so neither an inner guard ending nor an
    /// outer one can leave the process in the wrong mode. This is what a
    /// swap-and-restore got wrong across threads.
    #[test]
    #[serial_test::serial]
    fn dry_runs_nest() {
        assert!(!dry_run());
        {
            let _outer = DryRun::new();
            {
                let _inner = DryRun::new();
                assert!(dry_run());
            }
            assert!(dry_run(), "the outer guard is still in force");
        }
        assert!(!dry_run(), "and the process is back to executing");
    }
}
