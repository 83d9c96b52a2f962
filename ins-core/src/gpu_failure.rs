//! A step too large for the GPU, told apart from other internal failures.
//!
//! CubeCL reports a buffer it cannot allocate, or a kernel launch wider than the device allows,
//! by panicking where the data is next read, with a long chain of causes ("An error happened
//! during execution … can't allocate buffer of size: 6000000000", "Cube count too big (2000105,
//! 8, 1)"); wgpu's own validation says "Not enough memory left" or "Out of Memory". A user needs
//! one line: the step did not fit the GPU, and what to change. The CLI's panic report asks
//! [`memory_failure`] before printing an internal failure.

/// Phrases of CubeCL's and wgpu's allocation and launch-size failures (compared in lower case).
const MEMORY_PHRASES: [&str; 7] = [
    "cube count too big",
    "can't allocate buffer",
    "buffertoobig",
    "outofmemory",
    "out of memory",
    "not enough memory",
    "poolcapacityexceeded",
];

/// The line of `message` that says what did not fit, when `message` (a panic's text) is a GPU
/// allocation or launch-size failure.
pub fn memory_failure(message: &str) -> Option<&str> {
    message.lines().map(str::trim).find(|line| {
        let lower = line.to_lowercase();
        MEMORY_PHRASES.iter().any(|p| lower.contains(p))
    })
}

/// What to tell a user whose step did not fit the GPU (`gpu`: the backend and its adapter, as
/// [`crate::gpu::GpuRuntime::describe`] says them): the failure and the ways out.
pub fn memory_advice(gpu: Option<&str>, failure: &str) -> String {
    let on = gpu.map_or_else(String::new, |a| format!(" ({a})"));
    format!(
        "the step is too large for the GPU{on}: {failure}. Try a smaller scene \
         (--downscale 2 or more), fewer samples per step (--target-samples), a smaller patch \
         (--patch) in a new run, or --backend flex to run on the CPU"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What CubeCL 0.10 on lavapipe printed for a 6 GB tensor (read with `into_scalar`).
    const CUBECL_READ: &str = "Error while reading data: use `try_into_scalar` instead to \
catch the error at runtime: Execution(An error happened during execution
Caused by:
  Several failures at once
Caused by:
  The bytes were never written (failure #1, still claiming 2 buffer(s))
  skipped `ReduceKernel`: it needed memory ManagedMemoryId { value: 0 }, which carried the failure
Caused by:
  An IO error happened
Caused by:
  can't allocate buffer of size: 6000000000
No backtrace available
Asked at:
No backtrace available)";

    #[test]
    fn the_allocation_line_is_found_in_cubecls_chain_of_causes() {
        assert_eq!(
            memory_failure(CUBECL_READ),
            Some("can't allocate buffer of size: 6000000000")
        );
        assert_eq!(
            memory_failure(
                "wgpu error: Validation Error\n\nCaused by:\n    In Device::create_buffer\n    Not enough memory left."
            ),
            Some("Not enough memory left.")
        );
        assert_eq!(
            memory_failure("IoError::BufferTooBig { size: 9000000000 }"),
            Some("IoError::BufferTooBig { size: 9000000000 }")
        );
        // `train nerf --backend wgpu --target-samples 60000000` on lavapipe (a matmul's launch).
        assert_eq!(
            memory_failure(
                "the work writing it was skipped 23 operation(s) below a failure: Should run when selected by autotune.: matmul_naive: An unknown error happened.\nUnable to launch matmul because a required feature is unavailable: Cube count too big (2000105, 8, 1)\n"
            ),
            Some(
                "Unable to launch matmul because a required feature is unavailable: Cube count too big (2000105, 8, 1)"
            )
        );
    }

    #[test]
    fn other_failures_are_not_taken_for_memory() {
        for msg in [
            "index out of bounds: the len is 3 but the index is 7",
            "called `Option::unwrap()` on a `None` value",
            "Error while reading data: Execution(device lost)",
        ] {
            assert_eq!(memory_failure(msg), None, "{msg}");
        }
    }

    #[test]
    fn the_advice_names_the_backend_the_adapter_and_the_ways_out() {
        let a = memory_advice(
            Some("wgpu on NVIDIA H100 (Vulkan)"),
            "can't allocate buffer of size: 6000000000",
        );
        for part in [
            "wgpu",
            "NVIDIA H100",
            "6000000000",
            "--downscale",
            "--backend flex",
        ] {
            assert!(a.contains(part), "{part} missing from {a}");
        }
    }
}
