//! INS-rs patch (see `PATCHED.md`): NVRTC's automatic precompiled headers.
//!
//! CubeCL's generated CUDA C++ declares its integer types before the headers a kernel needs.
//! The asynchronous-copy matmuls include `<cuda/barrier>` and cooperative groups, whose
//! parsing costs about 0.95 s a kernel on a 2-core Xeon, and a cold run compiles dozens of
//! them (autotune's candidates). With `-pch` (NVRTC 12.8 and later), NVRTC parses a set of
//! headers once per process and reuses it, but only for headers included before any other
//! code; so the includes are moved to the top. The headers are self-contained (they compile
//! the same without CubeCL's typedefs above them).

use std::sync::OnceLock;

/// `CUBECL_NVRTC_PCH=0` turns precompiled headers off (to compare cold compile times).
const SWITCH: &str = "CUBECL_NVRTC_PCH";

/// Whether the NVRTC loaded has automatic precompiled headers (12.8 and later) and they are
/// not turned off.
pub(crate) fn nvrtc_has_pch() -> bool {
    static HAS: OnceLock<bool> = OnceLock::new();
    *HAS.get_or_init(|| {
        if std::env::var(SWITCH).is_ok_and(|v| v == "0") {
            return false;
        }
        let (mut major, mut minor) = (0, 0);
        // SAFETY: writes two integers; NVRTC is loaded (a kernel is being compiled).
        let ok = unsafe { cudarc::nvrtc::sys::nvrtcVersion(&mut major, &mut minor) };
        ok == cudarc::nvrtc::sys::nvrtcResult::NVRTC_SUCCESS && (major, minor) >= (12, 8)
    })
}

/// `source` with its `#include` lines first, each once, in their order; every other line
/// after them in its order.
pub(crate) fn includes_first(source: &str) -> String {
    let mut includes: Vec<&str> = Vec::new();
    let mut rest = String::with_capacity(source.len());
    for line in source.lines() {
        if line.trim_start().starts_with("#include") {
            if !includes.contains(&line) {
                includes.push(line);
            }
        } else {
            rest.push_str(line);
            rest.push('\n');
        }
    }
    let mut out = String::with_capacity(source.len() + 1);
    for line in includes {
        out.push_str(line);
        out.push('\n');
    }
    out.push_str(&rest);
    out
}

#[cfg(test)]
mod tests {
    use super::includes_first;

    #[test]
    fn includes_move_to_the_top_once_and_in_order() {
        let src = "typedef unsigned int uint32_t;\n#include <cuda/barrier>\nstruct a {};\n\
                   #include <mma.h>\n#include <cuda/barrier>\nextern \"C\" __global__ void k() {}\n";
        assert_eq!(
            includes_first(src),
            "#include <cuda/barrier>\n#include <mma.h>\ntypedef unsigned int uint32_t;\n\
             struct a {};\nextern \"C\" __global__ void k() {}\n"
        );
    }

    #[test]
    fn a_source_without_includes_is_unchanged() {
        let src = "typedef unsigned int uint32_t;\nextern \"C\" __global__ void k() {}\n";
        assert_eq!(includes_first(src), src);
    }
}
