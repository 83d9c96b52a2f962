#!/bin/bash
# Every CUDA kernel the program asks for, compiled here without a GPU (issue 48; by hand, not
# in CI: about 30 minutes on 2 cores, most of it NVRTC).
#
# `--backend cuda` has run on no GPU yet, and a lent GPU gives 15 minutes: a kernel that NVRTC
# refuses would spend them. So this runs the benchmark workloads and small training runs on
# `--backend cuda` against a stand-in for NVIDIA's driver (scripts/cuda_standin): NVIDIA's own
# NVRTC (from PyPI) compiles every kernel the runs ask for, autotune's candidates included, for
# an H100 (sm_90a) and assembles it (its CUBIN is what the program loads); the stand-in keeps
# each module and runs nothing; NVIDIA's ptxas assembles any module left as PTX. A run's numbers mean nothing here, except one: with no
# kernel running, a benchmark's `ms_per_step` is the host's own time for a step (Burn's
# autodiff and fusion, CubeCL's launches, the program's own host work), the floor under a GPU
# step on this CPU.
#
# Needs: python3 with venv and pip (PyPI reachable), gcc, the release binary
# (`cargo build --release -p ins-cli`), VGG-16's weights fetched (`ins-cli vgg fetch`).
# Settings: CUDA_MINOR (default 13.0, PyTorch cu130's; the wheels' version), W (work folder,
# default target/cuda-standin), BIN (default target/release/ins-cli), STEPS (bench steps, 3),
# HOST_STEPS (the host-time bench's steps, 10), STAGES (which runs, default all:
# bench nerf nerf_stylize idr idr_stylize host host_channel), KEEP_CACHE=1 (keep the last run's
# tuning and compiled kernels).
# Exit status 0 when every stage ran, every module compiled and assembled.
set -uo pipefail
W=${W:-target/cuda-standin}
BIN=${BIN:-target/release/ins-cli}
CUDA_MINOR=${CUDA_MINOR:-13.0}
STEPS=${STEPS:-3}
PYTHON=${PYTHON:-python3}
mkdir -p "$W"
W=$(cd "$W" && pwd)
BIN=$(realpath "$BIN")
t0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - t0 ))s] $*"; }

# NVIDIA's compiler pieces, as a machine with PyTorch's wheels and nvidia-cuda-crt has them.
if [ ! -f "$W/venv/.ready-$CUDA_MINOR" ]; then
  rm -rf "$W/venv"
  "$PYTHON" -m venv "$W/venv" || exit 1
  "$W/venv/bin/pip" install -q "nvidia-cuda-nvrtc==$CUDA_MINOR.*" "nvidia-cuda-runtime==$CUDA_MINOR.*" \
    "nvidia-cuda-crt==$CUDA_MINOR.*" "nvidia-cuda-nvcc==$CUDA_MINOR.*" nvidia-cuda-cccl || exit 1
  touch "$W/venv/.ready-$CUDA_MINOR"
fi
CU=$(echo "$W"/venv/lib/python3*/site-packages/nvidia/cu13)
[ -f "$CU/include/crt/mma.h" ] && [ -x "$CU/bin/ptxas" ] || { echo "no CUDA 13 wheels under $CU" >&2; exit 1; }
mkdir -p "$W/lib"
gcc -O1 -Wall -Wextra -shared -fPIC -I"$CU/include" scripts/cuda_standin/libcuda_standin.c \
  -o "$W/lib/libcuda.so" || exit 1
export CUDA_PATH=$CU LD_LIBRARY_PATH=$W/lib:$CU/lib RUST_BACKTRACE=0
# Autotune at `full`: every candidate compiled and tried, a superset of what a GPU's default
# (`balanced`) compiles. Below `full`, autotune bounds a round by the GPU's peak, which a CubeCL
# probe measures by timing kernels on the host's clock. Under the stand-in (nothing runs) the
# probe asks for a loop count past 32 bits and panics (cubecl-core's scalar.rs:78), and since
# the device tasks run in the caller's thread (the reentrant handle), the panic fails the step
# that asked for the tuning.
export CUBECL_AUTOTUNE_LEVEL=${CUBECL_AUTOTUNE_LEVEL:-full}
# A fresh kernel and tuning cache, so every candidate compiles; VGG-16's weights as fetched.
CACHE=${INS_CACHE_DIR:-$HOME/.cache/ins-rs}
[ "${KEEP_CACHE:-0}" = 1 ] || rm -rf "$W/cache"
rm -rf "$W/ptx" "$W/runs" "$W/logs"
mkdir -p "$W/cache" "$W/ptx" "$W/runs" "$W/logs"
[ -e "$W/cache/vgg16" ] || ln -s "$CACHE/vgg16" "$W/cache/vgg16"
export INS_CACHE_DIR=$W/cache
stamp "NVRTC $(ls "$CU"/lib/libnvrtc.so.* | head -1 | xargs basename), CUDA_PATH=$CU"

failed=0; guarded=0
stage() { # stage NAME command...: the run, its modules in $W/ptx/NAME, its output in $W/logs/NAME
  local name=$1; shift
  [[ " ${STAGES:-bench nerf nerf_stylize idr idr_stylize host host_channel} " == *" $name "* ]] || return 0
  mkdir -p "$W/ptx/$name"
  stamp "BEGIN $name: $*"
  STANDIN_PTX_DIR=$W/ptx/$name "$@" > "$W/logs/$name" 2>&1
  local rc=$?
  # Nothing computes on the stand-in, so a training run's parameters are whatever its buffers
  # held; the divergence guard may stop it at a check. Its steps' kernels were compiled by then.
  if (( rc != 0 )) && grep -q "made parameters non-finite at step" "$W/logs/$name"; then
    guarded=$((guarded + 1)); stamp "($name: stopped by the divergence guard on uncomputed values)"
  elif (( rc != 0 )); then
    failed=1; grep -v "^ " "$W/logs/$name" | tail -5
  fi
  stamp "END $name rc=$rc, $(ls "$W/ptx/$name" | wc -l) modules"
}
R=$W/runs
STYLE=${STYLE:-../shared/data/styles/starry_night.jpg}
stage bench "$BIN" bench --backend cuda --steps "$STEPS" siren vgg nerf-pretrain nerf-stylize \
  idr-pretrain nerf-grid nerf-grid-stylize hash-grid hash-grid-object
"$BIN" data synth --format blender --out "$R/synth" --size 32 > /dev/null
"$BIN" data synth --format dtu --out "$R/dtu" --size 48 --views 8 > /dev/null
stage nerf "$BIN" train nerf --scene "$R/synth" --out "$R/nerf" --steps 40 --eval-every 20 \
  --quiet --backend cuda
stage idr "$BIN" train idr --scene "$R/dtu" --out "$R/idr" --steps 40 --rays 256 --eval-every 20 \
  --quiet --backend cuda
# The stylizations start from runs pretrained on flex (a stand-in run may end without a checkpoint).
"$BIN" train nerf --scene "$R/synth" --out "$R/nerf_flex" --steps 40 --quiet --backend flex \
  > "$W/logs/nerf_flex" 2>&1 || { failed=1; tail -3 "$W/logs/nerf_flex"; }
"$BIN" train idr --scene "$R/dtu" --out "$R/idr_flex" --steps 40 --rays 256 --quiet --backend flex \
  > "$W/logs/idr_flex" 2>&1 || { failed=1; tail -3 "$W/logs/idr_flex"; }
stage nerf_stylize "$BIN" train nerf --from "$R/nerf_flex" --style "$STYLE" --out "$R/nerf_st" \
  --steps 6 --quiet --backend cuda
stage idr_stylize "$BIN" train idr --from "$R/idr_flex" --style "$STYLE" --out "$R/idr_st" \
  --steps 6 --quiet --backend cuda
# The host's time a step: the benchmark again, its kernels tuned and compiled by the first (the
# PTX is kept in the cache), over HOST_STEPS steps, through the program's device handle (the
# caller's thread), then through CubeCL's channels for comparison.
stage host "$BIN" bench --backend cuda --steps "${HOST_STEPS:-10}" siren vgg nerf-pretrain \
  nerf-stylize idr-pretrain nerf-grid nerf-grid-stylize
stage host_channel env CUBECL_DEVICE_HANDLE=channel "$BIN" bench --backend cuda \
  --steps "${HOST_STEPS:-10}" siren vgg nerf-pretrain nerf-stylize idr-pretrain nerf-grid \
  nerf-grid-stylize

# Every module assembled for the H100 (sm_90a), two at a time.
# NVRTC assembles for sm_90a itself and hands over its CUBIN (the patched cubecl-cuda); a module
# left as PTX (CUBECL_NVRTC_CUBIN=0) is assembled here.
stamp "ptxas on $(find "$W/ptx" -name '*.ptx' | wc -l) PTX modules"
find "$W/ptx" -name '*.ptx' | xargs -P2 -I{} sh -c \
  "'$CU/bin/ptxas' -arch=sm_90a -o /dev/null {} 2> {}.log || echo {}" > "$W/ptxas_failed.txt"
stamp "ptxas done: $(wc -l < "$W/ptxas_failed.txt") failed"
[ -s "$W/ptxas_failed.txt" ] && { failed=1; head -3 "$W/ptxas_failed.txt"; }

# NVRTC's refusals, and the throughput probe's panics (see CUBECL_AUTOTUNE_LEVEL above; none at
# `full`). A real GPU's timer does not do that.
refused=$(grep -l "Compilation Error" "$W"/logs/* 2>/dev/null | wc -l)
(( refused == 0 )) || { failed=1; grep -h -A3 "Compilation Error" "$W"/logs/* | head -20; }
probe=$(cat "$W"/logs/* | grep -c "frontend/scalar.rs:78")
other=$(grep -h "error: internal failure" "$W"/logs/* | grep -v -c "frontend/scalar.rs:78")
echo
echo "modules compiled by NVRTC: $(find "$W/ptx" -name '*.ptx' -o -name '*.cubin' | wc -l) ($(find "$W/ptx" -name '*.cubin' | wc -l) as CUBIN); NVRTC refusals: $refused"
echo "ptxas failures: $(wc -l < "$W/ptxas_failed.txt"); tensor-core (mma) modules among the PTX: $(grep -l -r 'mma.sync' "$W/ptx" --include='*.ptx' | wc -l)"
echo "throughput-probe panics (stand-in timing, see above): $probe; other internal failures: $other"
(( other == 0 )) || failed=1
echo "training runs stopped by the divergence guard (expected here): $guarded"
echo "host time a step (nothing runs on the stand-in; median and fastest of ${HOST_STEPS:-10} synced steps, ms):"
grep -h '^{' "$W/logs/host" "$W/logs/host_channel" 2>/dev/null | "$PYTHON" -c '
import json, sys
for line in sys.stdin:
    r = json.loads(line)
    print("  %-18s %-10s %8.1f  %8.1f" % (r["workload"], r.get("device_handle", ""), r["ms_per_step"], r["min_ms"]))'
stamp "done: $([ $failed = 0 ] && echo passed || echo FAILED)"
exit $failed
