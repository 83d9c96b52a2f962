#!/bin/bash
# Where a GPU step's time goes (issue 48), for the second call of a GPU session after check.sh.
# Run on the device machine from the repository root with .dev and .gl carried (pack.sh).
# - Kernel by kernel (CubeCL's profile, summed by profile_summary.py): VGG, the largest gap to
#   PyTorch (siren's step is mostly VGG), on wgpu and on CUDA (f32 and f16); a grid NeRF step, and the
#   NeRF pretraining and stylization steps PyTorch's reference also runs, on CUDA.
# - Sphere tracing's share: an IDR stylization traces its patch's rays against the frozen
#   surface every step (off a CPU its rounds on the device, four reads a trace); its metrics
#   log the tracing's wall time (`trace_ms`) beside the step's (`ms`).
# - SPIR-V instead of WGSL, where pack.sh packed a `--features spirv` binary (SPIRV_BIN;
#   scripts/spirv_check.sh proves that build on lavapipe first).
# Each stage under its own timeout, all under DEADLINE seconds; summaries go to $OUT.
DEADLINE=${DEADLINE:-300}
source scripts/gpu/lib.sh
unpack ins-cli; BIN=/tmp/ins-cli
restore_vgg
cuda_env
profiled() { # profiled NAME TIMEOUT args...: the run with CubeCL's kernel profile, summarized
  local name=$1 to=$2; shift 2
  stage "$name" "$to" env CUBECL_DEBUG_LOG=/tmp/$name.log CUBECL_DEBUG_OPTION=profile "$@"
  python3 scripts/gpu/profile_summary.py /tmp/$name.log > "$OUT/$name.txt" 2>&1
  # The raw lines too, should the summary miss any (xz through Python: the machine may lack xz).
  python3 -c "import lzma,shutil; shutil.copyfileobj(open('/tmp/$name.log','rb'), lzma.open('$OUT/$name.log.xz','wb'))"
  head -18 "$OUT/$name.txt"
}
step_times() { # step_times RUN: median ms a step and median trace_ms over the run's logged steps
  python3 - "$1/metrics.jsonl" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if '"ms"' in l]
for key in ("ms", "trace_ms"):
    v = [r[key] for r in rows[len(rows) // 4:] if key in r]
    if v:
        print(f"{key}: median {statistics.median(v):.1f} over {len(v)} steps")
PY
}
stamp "setup done"
profiled prof_vgg_wgpu 60 $BIN bench --backend wgpu --steps 2 vgg
profiled prof_vgg_cuda 60 $BIN bench --backend cuda --steps 2 vgg
# The same in f16 (check.sh's bench_cuda_f16 compiled its kernels): tensor-core convolutions?
profiled prof_vgg_cuda_f16 45 $BIN bench --backend cuda --steps 2 --precision f16 vgg
profiled prof_nerf_grid_cuda 60 $BIN bench --backend cuda --steps 2 nerf-grid
# The NeRF workloads PyTorch also runs (its MLP's matmuls, the sampling and compositing kernels).
profiled prof_nerf_cuda 60 $BIN bench --backend cuda --steps 2 nerf-pretrain nerf-stylize
stage synth 20 $BIN data synth --format dtu --out /tmp/dtu --size 128 --views 16
for backend in cuda wgpu; do
  stage idr_pretrain_$backend 60 $BIN train idr --scene /tmp/dtu --steps 300 --eval-every 0 \
    --out runs/idr_$backend --quiet --backend $backend
  stage idr_stylize_$backend 60 $BIN train idr --from runs/idr_$backend --style .dev/starry_night.jpg \
    --steps 60 --out runs/idr_st_$backend --quiet --backend $backend
  step_times runs/idr_st_$backend
done
if [ -f .dev/ins-cli-spirv.xz ]; then
  unpack ins-cli-spirv
  # VGG first: its convolutions are where cooperative matrices (tensor cores through Vulkan)
  # would count. Profiled, so a stage that runs out of time still shows how far it got.
  profiled prof_spirv 90 /tmp/ins-cli-spirv bench --backend wgpu --steps 3 vgg nerf-grid
fi
stamp "all done"
