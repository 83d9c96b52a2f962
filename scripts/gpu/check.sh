#!/bin/bash
# The GPU check (issue 28), run on the device machine from the repository root with .dev and
# .gl carried (scripts/gpu/pack.sh makes them). Each stage runs under its own timeout and
# everything goes to $OUT/log.txt; the whole script stays under 9 minutes.
OUT=${OUT:-/tmp/gpu_out}; mkdir -p "$OUT"
exec > >(tee -a "$OUT/log.txt") 2>&1
t0=$(date +%s.%N)
stamp() { python3 -c "import time; print(f'[{time.time()-$t0:7.1f}s] $*')"; }
stage() { # stage NAME TIMEOUT command...
  local name=$1 to=$2; shift 2
  stamp "BEGIN $name (timeout $to s): $*"
  local s; s=$(date +%s.%N)
  timeout -k 5 "$to" "$@"; local rc=$?
  stamp "END $name rc=$rc wall=$(python3 -c "print(round($(date +%s.%N)-$s, 2))") s"
}
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
nvidia-smi -L
python3 -c "import lzma,shutil; shutil.copyfileobj(lzma.open('.dev/ins-cli.xz'), open('/tmp/ins-cli','wb'))"
chmod +x /tmp/ins-cli; BIN=/tmp/ins-cli
read -r bpk onnx size mtime < .dev/vgg.meta
mkdir -p "$(dirname "$onnx")"
python3 -c "import lzma,shutil; shutil.copyfileobj(lzma.open('.dev/vgg.bpk.xz'), open('$(dirname "$onnx")/$bpk','wb'))"
cp .dev/"${bpk%.bpk}".json "$(dirname "$onnx")/"
truncate -s "$size" "$onnx"; touch -d "${mtime//_/ }" "$onnx"
export INS_CACHE_DIR=$(dirname "$(dirname "$onnx")")
R=runs/$(date +%s); mkdir -p "$R"
stamp "setup done"
stage siren 100 $BIN train siren --quiet --out $R/siren
stage siren_cached 40 $BIN train siren --quiet --out $R/siren_cached
stage lego_pretrain 170 $BIN train nerf --scene .dev/lego200 --out $R/lego --quiet --checkpoint-every 100 --backend wgpu
cut -c1-220 $R/lego/metrics.jsonl | tail -12
stage lego_stylize 120 $BIN train nerf --from $R/lego --style .dev/starry_night.jpg --out $R/lego_st --quiet --backend wgpu
cut -c1-220 $R/lego_st/metrics.jsonl | tail -4
cp $R/lego_st/val/final.png "$OUT/lego_stylized.png" 2>/dev/null
stage bench 60 $BIN bench --backend wgpu --steps 3 nerf-grid nerf-grid-stylize idr-pretrain hash-grid
stage torch 30 python3 .dev/torch_ref.py --device cuda --steps 5
stamp "all done"
