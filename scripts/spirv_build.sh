#!/bin/bash
# Builds the SPIR-V variant of the CLI into target/spirv/ins-cli: `--features spirv` makes
# CubeCL compile kernels to SPIR-V for Vulkan instead of WGSL, the path to cooperative matrices
# (tensor cores) through wgpu. Not the default build, and not built by CI (a second build of
# Burn's wgpu stack, about 10 minutes on 2 cores).
#
# CubeCL 0.11.3's SPIR-V compiler declares a kernel's shared memory wrongly on devices without
# explicit workgroup layouts (Mesa's lavapipe among them): invalid SPIR-V, on which lavapipe
# crashes. The fix (third_party/cubecl-spirv-0.11.3-shared-memory.patch) is applied to a copy of
# the crate under target/, given to cargo as a patch for this build only, so the repository's
# Cargo.toml and Cargo.lock stay as they are. The default build is put back at
# target/release/ins-cli afterwards.
set -euo pipefail
cd "$(dirname "$0")/.."
patched=target/cubecl-spirv-0.11.3-patched
if [ ! -f "$patched/.patched" ]; then
  cargo fetch --quiet
  src=$(find "${CARGO_HOME:-$HOME/.cargo}"/registry/src -maxdepth 1 -mindepth 1 -type d \
    -exec test -d {}/cubecl-spirv-0.11.3 \; -print -quit)
  [ -n "$src" ] || { echo "cubecl-spirv 0.11.3 is not in cargo's registry cache" >&2; exit 1; }
  rm -rf "$patched"
  cp -r "$src/cubecl-spirv-0.11.3" "$patched"
  patch -d "$patched" -p1 < third_party/cubecl-spirv-0.11.3-shared-memory.patch
  touch "$patched/.patched"
fi
cp Cargo.lock target/Cargo.lock.default
restore() { cp target/Cargo.lock.default Cargo.lock; }
trap restore EXIT
cargo build --release -p ins-cli --features spirv \
  --config "patch.crates-io.cubecl-spirv.path=\"$patched\""
mkdir -p target/spirv
cp target/release/ins-cli target/spirv/ins-cli
restore
cargo build --release -p ins-cli
echo "SPIR-V build: target/spirv/ins-cli"
