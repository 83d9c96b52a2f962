#!/usr/bin/env python3
"""Issue 48's table from one GPU check: each benchmark workload on the GPU (wgpu and CUDA), synced per
step and pipelined (steps back to back, one sync at the end, as PyTorch's reference times itself),
against PyTorch on the same GPU, and against 2 CPU cores where a file of `ins-cli bench` lines
from a CPU is given; then the wall time of every stage (the lego runs, the SIREN main job).

Usage: table.py LOG [CPU_BENCH_JSONL]   (LOG: the check's $OUT/log.txt)
"""
import json
import re
import sys


def json_lines(path):
    out = []
    try:
        text = open(path, encoding="utf-8", errors="replace").read()
    except OSError:
        return out
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("{") and '"workload"' in line:
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                pass
    return out


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    log = sys.argv[1]
    lines = json_lines(log)
    cpu = {l["workload"]: l for l in json_lines(sys.argv[2])} if len(sys.argv) > 2 else {}
    torch = {l["workload"]: l for l in lines if str(l.get("engine", "")).startswith("pytorch")}
    ours = {}  # (backend, workload) -> line
    for l in lines:
        if l.get("backend") in ("wgpu", "cuda"):
            name = l["workload"] + (" (f16)" if l.get("precision") == "f16" else "")
            name += " (channel)" if l.get("device_handle") == "channel" else ""
            name += " (rows unsplit)" if l.get("split_rows") is False else ""
            name += " (layers unfused)" if l.get("fused_mlp") is False else ""
            ours[(l["backend"], name)] = l
    fmt = lambda v: "–" if v is None else f"{v:.1f}"
    ratio = lambda a, b: "–" if a is None or not b else f"{a / b:.2f}×"
    print("| workload | wgpu ms/step synced / pipelined | CUDA ms/step synced / pipelined | PyTorch CUDA ms/step | best ÷ PyTorch (pipelined) | 2 CPU cores ms/step |")
    print("|---|---|---|---|---|---|")
    for name in sorted({n for _, n in ours} | set(torch)):
        base = name.split(" (")[0]
        w, c, t = ours.get(("wgpu", name), {}), ours.get(("cuda", name), {}), torch.get(base, {})
        ref = t.get("ms_per_step")
        piped = [v for v in (w.get("pipelined_ms_per_step"), c.get("pipelined_ms_per_step")) if v]
        best = min(piped) if piped else None
        cell = lambda o: f"{fmt(o.get('ms_per_step'))} / {fmt(o.get('pipelined_ms_per_step'))}"
        print(f"| {name} | {cell(w)} | {cell(c)} | {fmt(ref)} | {ratio(best, ref)} | "
              f"{fmt(cpu.get(base, {}).get('ms_per_step'))} |")
    print()
    print("| stage | wall s | exit |")
    print("|---|---|---|")
    for m in re.finditer(r"END (\S+) rc=(\d+) wall=([\d.]+) s", open(log, errors="replace").read()):
        print(f"| {m.group(1)} | {float(m.group(3)):.1f} | {m.group(2)} |")


if __name__ == "__main__":
    main()
