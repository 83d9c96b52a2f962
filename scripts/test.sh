#!/usr/bin/env bash
# The test suite: installs what is missing, then runs every test of the workspace.
# It builds into the same target folder as the README's main command (./target, release
# profile), so on a fresh machine Burn compiles once for both. The first run builds Burn
# (20 to 45 minutes on 2 cores, by CPU) and fetches VGG-16 (65 MB) once.
#
#   bash scripts/test.sh                 every test, two test programs at a time in two lanes
#                                        (lavapipe, CPU), the first starting during the build
#   bash scripts/test.sh -- FILTER      the same, passing FILTER to every test program
#   bash scripts/test.sh ARGS           plain `cargo test --release --workspace ARGS`
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# wgpu runs on Mesa's software Vulkan here: autotuning kernels there costs minutes and tells nothing.
export CUBECL_AUTOTUNE_LEVEL="${CUBECL_AUTOTUNE_LEVEL:-minimal}"
# ...and compiling them is most of the wgpu tests' time (LLVM inside Mesa): without its
# optimisation passes a cold `backends` took 261 s instead of 300 (Intel Xeon, 2 cores). The
# tests' kernels run on a few hundred values, where slower shader code costs nothing.
export GALLIVM_PERF="${GALLIVM_PERF:-nopt}"
# ...and most of what it compiles were CubeCL's tiled matmuls (50-250 KB of WGSL each, five
# candidates a size under tuning): each set's first candidate instead, nothing tuned (patched
# into third_party/cubecl-runtime-0.11.3). The tests compare our ops with flex; which matmul
# routine runs is CubeCL's choice, tuned on a GPU (scripts/gpu/check.sh).
export CUBECL_AUTOTUNE_FALLBACK="${CUBECL_AUTOTUNE_FALLBACK:-1}"
if [ $# -eq 0 ] || [ "$1" = "--" ]; then
  python3 scripts/run_tests.py "$@"
else
  cargo test --release --workspace "$@"
fi
