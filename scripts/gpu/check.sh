#!/bin/bash
# The GPU check (issues 28 and 48), run on the device machine from the repository root with .dev and
# .gl carried (scripts/gpu/pack.sh makes them). Stages run in order of importance, each under its
# own timeout and all under one deadline (DEADLINE seconds, default 560), so the call ends inside
# the device tool's 10 minutes whatever hangs; everything goes to $OUT/log.txt.
DEADLINE=${DEADLINE:-560}
source scripts/gpu/lib.sh
unpack ins-cli; BIN=/tmp/ins-cli
restore_vgg
R=runs/$(date +%s); mkdir -p "$R"
metrics() { cut -c1-240 "$1/metrics.jsonl" 2>/dev/null | tail -"$2"; }
cuda_env
stamp "setup done"
# 0. Burn's CUDA backend (NVRTC, tensor cores), never run before: the workloads PyTorch also
# runs, PyTorch itself (the grid workloads' counterparts in torch_grid_ref.py) and wgpu for the
# ratios, then the lego pretrain twice (cold, then with its kernels cached), its stylization
# and the SIREN main job.
CUDA_WORKLOADS="siren vgg nerf-pretrain nerf-stylize idr-pretrain nerf-grid"
stage bench_cuda 120 $BIN bench --backend cuda --steps 3 $CUDA_WORKLOADS
# A cold start that outlasts its stage leaves the later workloads unmeasured: they run again
# here, their kernels partly cached by then, so the table still gets every CUDA row.
missing=$(missing_rows cuda $CUDA_WORKLOADS)
[ -z "$missing" ] || stage bench_cuda_rest 90 $BIN bench --backend cuda --steps 3 $missing
# The same through CubeCL's own device threads and channels, which the program replaced by the
# caller's thread (third_party/cubecl-common-0.11.3/PATCHED.md): the table's "(channel)" rows.
stage bench_cuda_channel 60 env CUBECL_DEVICE_HANDLE=channel $BIN bench --backend cuda --steps 3 siren vgg nerf-pretrain nerf-grid
# The long sums taken whole (ins-core/src/kernels/dense_blocks.rs: a weight's or a bias's
# gradient, a Gram matrix, each on a few cubes, as before): the table's "(rows unsplit)" rows.
stage bench_cuda_unsplit 60 env INS_SPLIT_ROWS=0 $BIN bench --backend cuda --steps 3 nerf-pretrain nerf-grid idr-pretrain siren vgg
# The small MLPs layer by layer, as before ins-core/src/kernels/fused_mlp took the grid NeRF's
# and the stylization's chains in four kernels a step: the table's "(layers unfused)" rows.
stage bench_cuda_unfused 40 env INS_FUSED_MLP=0 $BIN bench --backend cuda --steps 3 nerf-grid nerf-grid-stylize
stage torch 40 python3 .dev/torch_ref.py --device cuda --steps 5
stage torch_grid 60 python3 scripts/torch_grid_ref.py --device cuda --steps 5
# VGG's convolutions in f16 on CUDA (tensor cores; opt-in until a GPU shows it faster and as
# good): the workloads with VGG, against their f32 rows above.
stage bench_cuda_f16 75 $BIN bench --backend cuda --steps 3 --precision f16 vgg siren nerf-grid-stylize nerf-stylize
stage bench_ref 90 $BIN bench --backend wgpu --steps 3 siren vgg nerf-pretrain nerf-stylize idr-pretrain nerf-grid
stage bench_wgpu_channel 45 env CUBECL_DEVICE_HANDLE=channel $BIN bench --backend wgpu --steps 3 siren nerf-grid
stage lego_pretrain_cuda_cold 120 $BIN train nerf --scene .dev/lego200 --out $R/lego_cuda --quiet --backend cuda
metrics $R/lego_cuda 3
stage lego_pretrain_cuda_warm 60 $BIN train nerf --scene .dev/lego200 --out $R/lego_cuda2 --quiet --backend cuda
metrics $R/lego_cuda2 3
stage lego_stylize_cuda 90 $BIN train nerf --from $R/lego_cuda --style .dev/starry_night.jpg --out $R/lego_st_cuda --quiet --backend cuda
metrics $R/lego_st_cuda 3; cp $R/lego_st_cuda/val/final.png "$OUT/lego_stylized_cuda.png" 2>/dev/null
# The same stylization with VGG in f16: its time, and its losses and picture against f32's.
stage lego_stylize_cuda_f16 60 $BIN train nerf --from $R/lego_cuda --style .dev/starry_night.jpg --out $R/lego_st_cuda_f16 --quiet --backend cuda --precision f16
metrics $R/lego_st_cuda_f16 3; cp $R/lego_st_cuda_f16/val/final.png "$OUT/lego_stylized_cuda_f16.png" 2>/dev/null
stage siren_cuda 30 $BIN train siren --quiet --out $R/siren_cuda --backend cuda
# The real VGG-16's features and style gradient in f16 against f32 on CUDA
# (tests/tests/library/vgg_import.rs; the wgpu run of the same test is the last stage). The test
# binary finds its fixtures where it was built.
library_test() { # library_test STAGE TIMEOUT [ENV=VALUE...] TEST
  [ -f .dev/library.xz ] || return
  [ -x /tmp/library ] || unpack library
  local src; src=$(cat .dev/source_root)
  [ -e "$src" ] || { mkdir -p "$(dirname "$src")"; ln -s "$PWD" "$src"; }
  local name=$1 limit=$2; shift 2
  (cd "$src/tests" && stage "$name" "$limit" env "${@:1:$#-1}" /tmp/library --ignored --exact \
    --nocapture "${@: -1}")
}
library_test vgg_f16_real_cuda 120 INS_GPU_TEST_BACKEND=cuda \
  vgg_import::f16_features_on_the_real_network_stay_close_to_f32
# 1. lego 200² with the defaults, kernels not yet compiled or tuned on this machine.
stage lego_pretrain_cold 200 $BIN train nerf --scene .dev/lego200 --out $R/lego --quiet --checkpoint-every 250 --backend wgpu
metrics $R/lego 14; cp $R/lego/val/final.png "$OUT/lego_pretrained.png" 2>/dev/null
# 2. An error after the device is up must exit 1, not crash in the driver's teardown.
stage exit_status 30 $BIN train nerf --scene .dev/lego200 --out $R/lego --quiet --backend wgpu
# 3. Stylize it (VGG's kernels compiled here for the first time).
stage lego_stylize_cold 150 $BIN train nerf --from $R/lego --style .dev/starry_night.jpg --out $R/lego_st --quiet --backend wgpu
metrics $R/lego_st 5; cp $R/lego_st/val/final.png "$OUT/lego_stylized.png" 2>/dev/null
# 4. The grid workloads on wgpu.
stage bench_new 100 $BIN bench --backend wgpu --steps 3 nerf-grid nerf-grid-stylize idr-pretrain hash-grid
# VGG in f16 (opt-in until a GPU shows it faster), against the f32 figure just above.
stage bench_f16 40 $BIN bench --backend wgpu --steps 3 --precision f16 vgg nerf-grid-stylize
# 5. The same runs again with every kernel cached: what a user's second run costs.
stage lego_pretrain_warm 90 $BIN train nerf --scene .dev/lego200 --out $R/lego2 --quiet --backend wgpu
metrics $R/lego2 3
stage lego_stylize_warm 90 $BIN train nerf --from $R/lego --style .dev/starry_night.jpg --out $R/lego_st2 --quiet --backend wgpu
metrics $R/lego_st2 3
stage siren 60 $BIN train siren --quiet --out $R/siren
# 6. The real VGG-16 in f16 against f32 on wgpu (ignored in CI, where lavapipe took ten
# minutes for it).
library_test vgg_f16_real 120 INS_GPU_TEST_BACKEND=wgpu \
  vgg_import::f16_features_on_the_real_network_stay_close_to_f32
stamp "all done"
# Issue 48's table: GPU (synced and pipelined) against PyTorch on the same GPU and 2 CPU cores.
python3 scripts/gpu/table.py "$OUT/log.txt" $([ -f .dev/cpu_bench.jsonl ] && echo .dev/cpu_bench.jsonl) > "$OUT/table.md"
cat "$OUT/table.md"
