#!/bin/bash
# Proves the SPIR-V build on this machine's Vulkan (lavapipe where there is no GPU): `--features
# spirv` makes CubeCL compile kernels to SPIR-V for Vulkan instead of WGSL, the path to
# cooperative matrices (tensor cores) through wgpu. CI does not build it (a second build of
# Burn's wgpu stack, about 10 minutes here), so run this after changing CubeCL or its patch in
# third_party/.
#
# It builds the feature (scripts/spirv_build.sh: target/spirv/ins-cli), trains three small
# runs on both builds with --backend wgpu (a grid NeRF, a volume-rendered IDR, a SIREN
# stylization through VGG), compares their logged losses (SPIR-V against WGSL within 1e-3, the
# tolerance the suite holds wgpu to against flex; measured up to 1e-4), and validates every
# SPIR-V module the runs compiled with spirv-val (Debian's spirv-tools: `apt-get install
# spirv-tools`). Exits 1 on a difference or an invalid module. About 33 minutes on 2 cores with
# cold caches: 12 to build, 20 for the six runs on lavapipe.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v spirv-val >/dev/null || { echo "spirv-val not found: apt-get install spirv-tools" >&2; exit 2; }
bash scripts/spirv_build.sh
work=$(mktemp -d /tmp/spirv_check.XXXX)
export CUBECL_AUTOTUNE_LEVEL=minimal GALLIVM_PERF=nopt
wgsl=target/release/ins-cli spirv=target/spirv/ins-cli
$wgsl data synth --format blender --size 32 --out "$work/blender" >/dev/null
$wgsl data synth --format dtu --size 32 --out "$work/dtu" >/dev/null
runs=(
  "nerf|train nerf --scene $work/blender --steps 20 --target-samples 4096 --log2-table 12 --max-resolution 64 --occupancy-resolution 16 --eval-every 0"
  "idr|train idr --scene $work/dtu --holdout 4 --steps 6 --rays 64 --grid-max-resolution 64 --grid-table 12 --color-grid 63 --eval-every 0"
  "siren|train siren --size 32 --fit-steps 10 --stylize-steps 3"
)
failed=0
for r in "${runs[@]}"; do
  name=${r%%|*} args=${r#*|}
  for build in wgsl spirv; do
    bin=${!build} log=
    [ $build = spirv ] && log=$work/$name.compile.log
    start=$(date +%s)
    # shellcheck disable=SC2086
    CUBECL_DEBUG_LOG=${log:-0} CUBECL_DEBUG_OPTION=${log:+debug} INS_CACHE_DIR=$work/cache_$build \
      timeout 1500 $bin $args --backend wgpu --quiet --out "$work/$name.$build" > "$work/$name.$build.txt" 2>&1 \
      || { echo "$name on $build failed: see $work/$name.$build.txt"; failed=1; }
    echo "$name on $build: $(( $(date +%s) - start )) s"
  done
  python3 - "$work/$name.wgsl/metrics.jsonl" "$work/$name.spirv/metrics.jsonl" <<'PY' || failed=1
import json, sys
def losses(p):
    return {r["step"]: r["loss"] for r in map(json.loads, open(p)) if "loss" in r}
w, s = map(losses, sys.argv[1:])
worst = max(abs(s[k] - w[k]) / max(abs(w[k]), 1e-12) for k in w) if w.keys() == s.keys() and w else None
print(f"  {len(w)} logged losses, last WGSL {w[max(w)]:.9g} SPIR-V {s.get(max(w))}, largest relative difference {worst}")
sys.exit(0 if worst is not None and worst < 1e-3 else 1)
PY
  python3 scripts/spirv_validate.py "$work/$name.compile.log" "$work/$name.modules" | tail -5 || failed=1
done
echo "work folder: $work"
exit $failed
