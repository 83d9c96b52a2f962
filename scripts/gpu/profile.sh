#!/bin/bash
# Where a wgpu step's time goes on a GPU (issue 28), kernel by kernel, and whether compiling
# kernels to SPIR-V instead of WGSL changes it. Run on the device machine from the repository
# root with .dev and .gl carried: .dev holds ins-cli.xz (the default build), ins-cli-spirv.xz
# (`--features spirv`) and lego200 (scripts/gpu/pack.sh). Each stage under its own timeout, all
# under DEADLINE seconds; summaries go to $OUT.
DEADLINE=${DEADLINE:-240}
source scripts/gpu/lib.sh
unpack ins-cli; unpack ins-cli-spirv
WGSL=/tmp/ins-cli; SPIRV=/tmp/ins-cli-spirv
profiled() { # profiled NAME TIMEOUT args...: the run with CubeCL's kernel profile, summarized
  local name=$1 to=$2; shift 2
  stage "$name" "$to" env CUBECL_DEBUG_LOG=/tmp/$name.log CUBECL_DEBUG_OPTION=profile "$@"
  python3 scripts/gpu/profile_summary.py /tmp/$name.log > "$OUT/$name.txt" 2>&1
  head -18 "$OUT/$name.txt"
}
stamp "setup done"
profiled prof_nerf_grid 70 $WGSL bench --backend wgpu --steps 2 nerf-grid
stage wgsl_hash 30 $WGSL bench --backend wgpu --steps 3 hash-grid-object hash-grid
stage spirv_bench 70 $SPIRV bench --backend wgpu --steps 3 hash-grid-object nerf-grid
profiled prof_lego 90 $WGSL train nerf --scene .dev/lego200 --steps 70 --eval-every 0 --quiet --backend wgpu --out runs/prof_lego
cut -c1-200 runs/prof_lego/metrics.jsonl 2>/dev/null | tail -3
stamp "all done"
