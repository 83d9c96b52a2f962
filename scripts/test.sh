#!/usr/bin/env bash
# The test suite: installs what is missing, then runs every test of the workspace.
# It builds into the same target folder as the README's main command (./target, release
# profile), so on a fresh machine Burn compiles once for both. The first run builds Burn
# (20 to 50 minutes on 2 cores, by CPU) and fetches VGG-16 (65 MB) once.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# wgpu runs on Mesa's software Vulkan here: autotuning kernels there costs minutes and tells nothing.
export CUBECL_AUTOTUNE_LEVEL="${CUBECL_AUTOTUNE_LEVEL:-minimal}"
cargo test --release --workspace "$@"
