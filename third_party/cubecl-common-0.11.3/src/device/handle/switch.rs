//! INS-rs's patch: the device handle chosen when the process starts, not when CubeCL is built.
//!
//! CubeCL 0.11 reaches each device service (Burn's fusion, the runtime's server) through a
//! thread of its own and a spinning 32-task channel. Where the host's work per operation is a
//! few microseconds, the hand-offs cost more than the work: on a 2-core machine a SIREN step's
//! host time was 40 ms through the channels and 6 ms in the caller's thread
//! (docs/measurements.md, forty-fourth session). The reentrant handle, CubeCL's own for
//! single-threaded targets, runs every task in the calling thread under a reentrant lock.
//!
//! `CUBECL_DEVICE_HANDLE=channel` gives CubeCL's default back; `reentrant` (or nothing) keeps
//! the caller's thread. The choice is read once, at the first handle, and holds for the process.

use core::any::Any;
use std::sync::OnceLock;

use super::channel::ChannelDeviceHandle;
use super::reentrant::ReentrantMutexDeviceHandle;
use super::{CallError, DeviceHandleSpec, ServiceCreationError};
use crate::device::{DeviceId, DeviceService, ServerUtilitiesHandle};

/// The variable that chooses the handle.
pub const DEVICE_HANDLE_VAR: &str = "CUBECL_DEVICE_HANDLE";

/// How device services are reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceHandleKind {
    /// A thread per device service, fed through spinning channels (CubeCL's default).
    Channel,
    /// The caller's thread, under a reentrant lock.
    Reentrant,
}

impl DeviceHandleKind {
    /// The kind a value of [`DEVICE_HANDLE_VAR`] names (`None` for an unknown name).
    pub fn parse(value: &str) -> Option<Self> {
        match value.trim() {
            "channel" => Some(Self::Channel),
            "reentrant" | "" => Some(Self::Reentrant),
            _ => None,
        }
    }

    /// The kind this process uses: [`DEVICE_HANDLE_VAR`]'s, read once; reentrant when it is
    /// unset or unknown.
    pub fn current() -> Self {
        static KIND: OnceLock<DeviceHandleKind> = OnceLock::new();
        *KIND.get_or_init(|| {
            std::env::var(DEVICE_HANDLE_VAR)
                .ok()
                .and_then(|v| Self::parse(&v))
                .unwrap_or(Self::Reentrant)
        })
    }
}

/// A handle of the process's kind.
#[derive(Clone)]
pub enum SwitchedDeviceHandle {
    /// CubeCL's channel.
    Channel(ChannelDeviceHandle),
    /// The caller's thread.
    Reentrant(ReentrantMutexDeviceHandle),
}

impl DeviceHandleSpec for SwitchedDeviceHandle {
    // Only collective operations (several devices) look at this; they need the channel.
    const BLOCKING: bool = false;

    fn insert<S: DeviceService>(
        device_id: DeviceId,
        service: S,
    ) -> Result<Self, ServiceCreationError> {
        Ok(match DeviceHandleKind::current() {
            DeviceHandleKind::Channel => {
                Self::Channel(ChannelDeviceHandle::insert::<S>(device_id, service)?)
            }
            DeviceHandleKind::Reentrant => Self::Reentrant(
                <ReentrantMutexDeviceHandle as DeviceHandleSpec>::insert::<S>(device_id, service)?,
            ),
        })
    }

    fn new<S: DeviceService>(device_id: DeviceId) -> Self {
        match DeviceHandleKind::current() {
            DeviceHandleKind::Channel => Self::Channel(ChannelDeviceHandle::new::<S>(device_id)),
            DeviceHandleKind::Reentrant => Self::Reentrant(
                <ReentrantMutexDeviceHandle as DeviceHandleSpec>::new::<S>(device_id),
            ),
        }
    }

    fn device_id(&self) -> DeviceId {
        match self {
            Self::Channel(h) => h.device_id(),
            Self::Reentrant(h) => h.device_id(),
        }
    }

    fn utilities(&self) -> ServerUtilitiesHandle {
        match self {
            Self::Channel(h) => h.utilities(),
            Self::Reentrant(h) => h.utilities(),
        }
    }

    fn flush_queue(&self) {
        match self {
            Self::Channel(h) => h.flush_queue(),
            Self::Reentrant(h) => h.flush_queue(),
        }
    }

    fn submit_blocking<'a, R: Send, T: FnOnce(&mut dyn Any) -> R + Send + 'a>(
        &self,
        task: T,
    ) -> Result<R, CallError> {
        match self {
            Self::Channel(h) => h.submit_blocking(task),
            Self::Reentrant(h) => h.submit_blocking(task),
        }
    }

    fn submit<T: FnOnce(&mut dyn Any) + Send + 'static>(&self, task: T) {
        match self {
            Self::Channel(h) => h.submit(task),
            Self::Reentrant(h) => h.submit(task),
        }
    }

    fn exclusive<R: Send, T: FnOnce() -> R + Send>(&self, task: T) -> Result<R, CallError> {
        match self {
            Self::Channel(h) => h.exclusive(task),
            Self::Reentrant(h) => h.exclusive(task),
        }
    }

    fn shutdown(device_id: DeviceId) {
        match DeviceHandleKind::current() {
            DeviceHandleKind::Channel => ChannelDeviceHandle::shutdown(device_id),
            DeviceHandleKind::Reentrant => ReentrantMutexDeviceHandle::shutdown(device_id),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::DeviceHandleKind;

    #[test]
    fn the_variable_names_a_kind_and_nothing_means_reentrant() {
        assert_eq!(DeviceHandleKind::parse("channel"), Some(DeviceHandleKind::Channel));
        assert_eq!(DeviceHandleKind::parse(" reentrant\n"), Some(DeviceHandleKind::Reentrant));
        assert_eq!(DeviceHandleKind::parse(""), Some(DeviceHandleKind::Reentrant));
        assert_eq!(DeviceHandleKind::parse("threads"), None);
    }
}
