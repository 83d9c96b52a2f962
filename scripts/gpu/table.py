#!/usr/bin/env python3
"""Issue 48's table from one GPU check: each benchmark workload on the GPU (wgpu), synced per step
and pipelined (steps back to back, one sync at the end, as PyTorch's reference times itself),
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
    ours = {}
    for l in lines:
        if l.get("backend") == "wgpu":
            ours[l["workload"] + (" (f16)" if l.get("precision") == "f16" else "")] = l
    fmt = lambda v: "–" if v is None else f"{v:.1f}"
    ratio = lambda a, b: "–" if a is None or not b else f"{a / b:.2f}×"
    print("| workload | GPU ms/step (synced) | GPU ms/step (pipelined) | PyTorch CUDA ms/step | GPU ÷ PyTorch (pipelined / synced) | 2 CPU cores ms/step |")
    print("|---|---|---|---|---|---|")
    for name in sorted(set(ours) | set(torch)):
        base = name.split(" (")[0]
        o, t, c = ours.get(name, {}), torch.get(base, {}), cpu.get(base, {})
        synced, piped = o.get("ms_per_step"), o.get("pipelined_ms_per_step")
        ref = t.get("ms_per_step")
        print(f"| {name} | {fmt(synced)} | {fmt(piped)} | {fmt(ref)} | "
              f"{ratio(piped, ref)} / {ratio(synced, ref)} | {fmt(c.get('ms_per_step'))} |")
    print()
    print("| stage | wall s | exit |")
    print("|---|---|---|")
    for m in re.finditer(r"END (\S+) rc=(\d+) wall=([\d.]+) s", open(log, errors="replace").read()):
        print(f"| {m.group(1)} | {float(m.group(3)):.1f} | {m.group(2)} |")


if __name__ == "__main__":
    main()
