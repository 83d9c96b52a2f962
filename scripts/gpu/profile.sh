#!/bin/bash
# Where a wgpu step's time goes on a GPU (issue 28), kernel by kernel, and whether compiling
# kernels to SPIR-V instead of WGSL changes it. Run on the device machine from the repository
# root with .dev and .gl carried: .dev holds ins-cli.xz (the default build), ins-cli-spirv.xz
# (`--features spirv`) and lego200 (scripts/gpu/pack.sh). Each stage under its own timeout, all
# under DEADLINE seconds; summaries go to $OUT.
OUT=${OUT:-/tmp/gpu_out}; mkdir -p "$OUT"
DEADLINE=${DEADLINE:-240}
exec > >(tee -a "$OUT/log.txt") 2>&1
t0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - t0 ))s] $*"; }
stage() { # stage NAME TIMEOUT command...: skipped when the deadline leaves under 15 s
  local name=$1 to=$2; shift 2
  local left=$(( DEADLINE - ($(date +%s) - t0) ))
  (( left < 15 )) && { stamp "SKIP $name (deadline)"; return; }
  (( to > left )) && to=$left
  stamp "BEGIN $name (timeout $to s): $*"
  local s; s=$(date +%s.%N)
  timeout -k 5 "$to" "$@"; local rc=$?
  stamp "END $name rc=$rc wall=$(python3 -c "print(round($(date +%s.%N)-$s, 2))") s"
}
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
nvidia-smi -L
for b in ins-cli ins-cli-spirv; do
  python3 -c "import lzma,shutil; shutil.copyfileobj(lzma.open('.dev/$b.xz'), open('/tmp/$b','wb'))"
  chmod +x /tmp/$b
done
WGSL=/tmp/ins-cli; SPIRV=/tmp/ins-cli-spirv
profiled() { # profiled NAME TIMEOUT args...: the run with CubeCL's kernel profile, summarized
  local name=$1 to=$2; shift 2
  stage "$name" "$to" env CUBECL_DEBUG_LOG=/tmp/$name.log CUBECL_DEBUG_OPTION=profile "$@"
  python3 scripts/gpu/profile_summary.py /tmp/$name.log > "$OUT/$name.txt" 2>&1
  head -18 "$OUT/$name.txt"
}
stamp "setup done"
profiled prof_nerf_grid 70 $WGSL bench --backend wgpu --steps 2 nerf-grid
stage spirv_bench 70 $SPIRV bench --backend wgpu --steps 3 hash-grid-object nerf-grid
stage wgsl_hash 30 $WGSL bench --backend wgpu --steps 3 hash-grid-object hash-grid
profiled prof_lego 90 $WGSL train nerf --scene .dev/lego200 --steps 70 --eval-every 0 --quiet --backend wgpu --out runs/prof_lego
cut -c1-200 runs/prof_lego/metrics.jsonl 2>/dev/null | tail -3
stamp "all done"
