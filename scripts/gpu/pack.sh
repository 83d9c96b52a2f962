#!/bin/bash
# Packs what a GPU check needs into .dev/ (ignored by git; about 50 MB, under the device tool's
# 64 MiB): the release binary and the real-VGG f16 test stripped and xz-compressed (the test
# left out, with a warning, where it would pass 64 MiB), the converted VGG-16 weights, lego at
# 200² (every 4th val view), a painting, PyTorch's benchmark program, and Vulkan's loader and
# libglvnd as .deb files in .gl/ (NVIDIA's Vulkan driver needs libGLdispatch), and CUDA's crt/
# headers as wheels in .gl/crt/ (the CUDA backend's tensor-core kernels need them).
# Run from the repository root after `cargo build --release -p ins-cli` and `ins-cli vgg fetch`.
# PYTHON must have Pillow (for the 200² lego). For profile.sh's SPIR-V stage: SPIRV_BIN names a
# binary built with `--features spirv` (packed as ins-cli-spirv.xz), and VGG=0 leaves the weights
# out (two binaries and VGG do not fit the 64 MiB together; profile.sh's IDR stylization then
# stops at its start). DEV names the folder (default .dev): a second pack, e.g. DEV=.dev_spirv
# with SPIRV_BIN and VGG=0, can wait beside the first for profile.sh's call (carry it, then
# `rm -rf .dev && mv .dev_spirv .dev` on the device before the script).
set -euo pipefail
DEV=${DEV:-.dev}
SHARED=${SHARED:-../shared}
PYTHON=${PYTHON:-python3}
CACHE=${INS_CACHE_DIR:-$HOME/.cache/ins-rs}
grep -qx "/$DEV/" .git/info/exclude 2>/dev/null || echo "/$DEV/" >> .git/info/exclude
grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo /.gl/ >> .git/info/exclude
mkdir -p "$DEV" .gl
strip -o /tmp/ins-cli.stripped target/release/ins-cli
xz -9 -T2 -c /tmp/ins-cli.stripped > $DEV/ins-cli.xz
if [ -n "${SPIRV_BIN:-}" ]; then
  strip -o /tmp/ins-cli-spirv.stripped "$SPIRV_BIN"
  xz -9 -T2 -c /tmp/ins-cli-spirv.stripped > $DEV/ins-cli-spirv.xz
else
  rm -f $DEV/ins-cli-spirv.xz
fi
# The real VGG-16's f16 check, in the library's test program (ignored in CI: see
# tests/tests/library/vgg_import.rs), with the folder it was built in (it reads its fixtures
# from there).
vgg_test=$(cargo test --release -p ins-tests --test library --no-run --message-format=json \
  | "$PYTHON" -c 'import json,sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("executable") and m.get("target", {}).get("name") == "library": print(m["executable"])')
strip -o /tmp/library.stripped "$vgg_test"
xz -9 -T2 -c /tmp/library.stripped > $DEV/library.xz
pwd > $DEV/source_root
if [ "${VGG:-1}" != 0 ]; then
# The converted weights are found by a key of the ONNX file's path, size and modification time:
# the check recreates an empty file with the same three at the same path.
onnx=$CACHE/vgg16/vgg16_imagenet_tf2onnx.onnx
bpk=$(ls "$CACHE"/vgg16/converted-*.bpk | head -1)
xz -9 -T2 -c "$bpk" > $DEV/vgg.bpk.xz
cp "${bpk%.bpk}.json" $DEV/
echo "$(basename "$bpk") $onnx $(stat -c %s "$onnx") $(stat -c %y "$onnx" | sed 's/ /_/g')" > $DEV/vgg.meta
else
  rm -f $DEV/vgg.bpk.xz $DEV/vgg.meta $DEV/converted-*.json
fi
cp "$SHARED/data/styles/starry_night.jpg" "$SHARED/bench/torch_ref.py" $DEV/
# The CPU column of check.sh's table: `ins-cli bench` lines from this machine, if written to
# target/cpu_bench.jsonl before packing (e.g. `ins-cli bench siren vgg nerf-pretrain
# nerf-stylize nerf-grid nerf-grid-stylize idr-pretrain > target/cpu_bench.jsonl`).
if [ -f target/cpu_bench.jsonl ]; then cp target/cpu_bench.jsonl $DEV/; else rm -f $DEV/cpu_bench.jsonl; fi
"$PYTHON" - "$SHARED/data/nerf_synthetic/lego" $DEV/lego200 <<'PY'
import json, os, sys
from PIL import Image
src, dst = sys.argv[1], sys.argv[2]
for split, every in (("train", 1), ("val", 4)):
    os.makedirs(f"{dst}/{split}", exist_ok=True)
    t = json.load(open(f"{src}/transforms_{split}.json"))
    t["frames"] = t["frames"][::every]
    for fr in t["frames"]:
        p = fr["file_path"]
        Image.open(f"{src}/{p}.png").resize((200, 200), Image.BOX).save(f"{dst}/{p[2:]}.png", optimize=True)
    json.dump(t, open(f"{dst}/transforms_{split}.json", "w"))
PY
# CUDA's crt/ headers, which the tensor-core matmuls' <mma.h> includes and PyTorch's wheels lack
# (nvidia-cuda-crt; found by scripts/cuda_compile_check.sh): one wheel per CUDA 13 minor
# version, about 130 kB each; lib.sh's cuda_env takes the one matching the GPU machine's NVRTC.
rm -rf .gl/crt && mkdir -p .gl/crt
for v in 13.0 13.1 13.2; do
  "$PYTHON" -m pip download -q --no-deps -d .gl/crt "nvidia-cuda-crt==$v.*"
done
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p /tmp/amd64/partial
apt-get $o update >/dev/null
(cd .gl && apt-get $o download libvulkan1 libglvnd0 libegl1 libgl1 libglx0 >/dev/null)
if (( $(du -sb "$DEV" .gl | awk '{s+=$1} END {print s}') > 63 * 1024 * 1024 )); then
  echo "warning: $DEV and .gl pass 63 MiB: leaving the real-VGG f16 test out" >&2
  rm -f $DEV/library.xz
fi
du -sh "$DEV" .gl
