#!/usr/bin/env bash
# Ours / PyTorch on this machine, in one command: sets up a venv with PyTorch (CPU), then for
# each workload of BENCHMARKS.md runs the PyTorch reference and `ins-cli bench` back to back,
# with the same thread count, and prints the ratios (below 1: INS-rs is faster).
#
#   scripts/bench_vs_torch.sh [--steps N] [--threads T] [--precision f32|bf16] [WORKLOAD ...]
#
# --precision is INS-rs's VGG arithmetic (default: as `ins-cli`, bf16 on AMX where the CPU has
# it, else f32); PyTorch stays in f32, as a user would run it.
# Workloads: vgg siren nerf-pretrain nerf-stylize (default: these four), nerf-grid idr-pretrain.
# The reference program is ../shared/bench/torch_ref.py (override with INS_TORCH_REF), and for
# the two grid workloads scripts/torch_grid_ref.py; the venv is .venv-torch (override with
# INS_TORCH_VENV). Results also go to bench_vs_torch.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."

steps=3
threads=2
precision=()
workloads=()
while (($#)); do
  case "$1" in
    --steps) steps="$2"; shift 2 ;;
    --threads) threads="$2"; shift 2 ;;
    --precision) precision=(--precision "$2"); shift 2 ;;
    -h|--help) sed -n 2,14p "$0"; exit 0 ;;
    *) workloads+=("$1"); shift ;;
  esac
done
((${#workloads[@]})) || workloads=(vgg siren nerf-pretrain nerf-stylize)

ref="${INS_TORCH_REF:-../shared/bench/torch_ref.py}"
[ -f "$ref" ] || { echo "no PyTorch reference at $ref (set INS_TORCH_REF)" >&2; exit 1; }
venv="${INS_TORCH_VENV:-.venv-torch}"
if ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
  echo "setting up $venv with PyTorch (CPU)" >&2
  python3 -m venv "$venv"
  # The CPU-only wheel is small; where its index is unreachable, PyPI's wheel works too.
  "$venv/bin/pip" install -q torch --index-url https://download.pytorch.org/whl/cpu 2>/dev/null \
    || "$venv/bin/pip" install -q torch
fi
cargo build --release -q -p ins-cli
cli=target/release/ins-cli

out=bench_vs_torch.jsonl
: > "$out"
for w in "${workloads[@]}"; do
  echo "== $w: PyTorch, then INS-rs ($steps steps each after a warm-up)" >&2
  program=$ref
  case "$w" in nerf-grid|idr-pretrain) program=scripts/torch_grid_ref.py ;; esac
  OMP_NUM_THREADS="$threads" "$venv/bin/python" "$program" --threads "$threads" --steps "$steps" "$w" \
    | grep '^{' >> "$out"
  RAYON_NUM_THREADS="$threads" "$cli" bench "$w" --steps "$steps" "${precision[@]}" \
    | grep '^{' >> "$out"
done

python3 - "$out" <<'EOF'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
torch = {r["workload"]: r for r in rows if str(r.get("engine", "")).startswith("pytorch")}
ours = {r["workload"]: r for r in rows if "backend" in r}
print(f"{'workload':<14}{'PyTorch ms':>12}{'INS-rs ms':>12}{'ratio':>8}  INS-rs precision")
for w, t in torch.items():
    if w in ours:
        a, b = t["ms_per_step"], ours[w]["ms_per_step"]
        print(f"{w:<14}{a:>12.0f}{b:>12.0f}{b / a:>8.2f}  {ours[w].get('precision', 'f32')}")
EOF
