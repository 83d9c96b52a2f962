#!/usr/bin/env python3
"""Which lines of the workspace ask for a step's kernel launches, from the CUDA stand-in's log.

    launch_sites.py BIN LOG                  launches in LOG by workspace line
    launch_sites.py BIN LOG_A LOG_B STEPS    launches a step: (LOG_B - LOG_A) / STEPS

BIN is the program that wrote the logs (its symbols name the addresses, through binutils'
addr2line); each log is one run with STANDIN_LAUNCH_LOG and STANDIN_BACKTRACE set (see
libcuda_standin.c). A launch is put on the innermost line of the stack that lies in this
workspace. Under Burn's fusion, operations are queued and run when something needs their
result, so a launch can land on the line that flushed the queue rather than the one that asked:
the backward pass (`trainer.rs`'s `backward()`) collects most of its own. Two runs of
`ins-cli bench --steps N` off a CPU take 2N + 1 steps each (a warm-up, N timed, N back to
back), so `--steps 3` and `--steps 8` differ by 10.
"""

import collections
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))) + "/"


def read_log(path):
    """[(kernel, [offsets])] of every launch in the log, its frames innermost first."""
    launches = []
    with open(path) as f:
        for line in f:
            if line.startswith("launch "):
                name = line.split()[1].split(":", 1)[1]
                launches.append((re.sub(r"_[0-9a-f]{8}$", "", name), []))
            elif line.startswith("  bt ") and launches:
                launches[-1][1].append(int(line.split()[1], 16))
    return launches


def name_frames(binary, offsets):
    """{offset: [(function, file:line)]} innermost inlined frame first, by addr2line."""
    # A return address points past its call: the call's line is the byte before.
    query = "\n".join(hex(o - 1) for o in offsets)
    out = subprocess.run(
        ["addr2line", "-a", "-f", "-C", "-i", "-e", binary],
        input=query, capture_output=True, text=True, check=True,
    ).stdout.splitlines()
    frames, current, i = {}, None, 0
    while i < len(out):
        if out[i].startswith("0x"):
            current = int(out[i], 16) + 1
            frames[current] = []
            i += 1
        else:
            frames[current].append((out[i], out[i + 1] if i + 1 < len(out) else "?"))
            i += 2
    return frames


def site(stack, frames):
    for offset in stack:
        for function, place in frames.get(offset, []):
            if place.startswith(ROOT) and "/third_party/" not in place:
                short = function.split("::")[-1].split("<")[0] or function
                return f"{place[len(ROOT):]} ({short})"
    return "(outside the workspace)"


def count(launches, frames):
    by_site, by_kernel = collections.Counter(), collections.Counter()
    for kernel, stack in launches:
        where = site(stack, frames)
        by_site[where] += 1
        by_kernel[(where, kernel)] += 1
    return by_site, by_kernel


def main():
    if len(sys.argv) not in (3, 5):
        sys.exit(__doc__)
    binary, logs = sys.argv[1], sys.argv[2:4] if len(sys.argv) == 5 else sys.argv[2:3]
    steps = float(sys.argv[4]) if len(sys.argv) == 5 else 1.0
    runs = [read_log(log) for log in logs]
    if not any(stack for run in runs for _, stack in run):
        sys.exit("no backtraces in the log: run with STANDIN_BACKTRACE set")
    frames = name_frames(binary, sorted({o for run in runs for _, s in run for o in s}))
    counted = [count(run, frames) for run in runs]
    for table, title in ((0, "launches by line"), (1, "launches by line and kernel")):
        after = counted[-1][table]
        before = counted[0][table] if len(counted) == 2 else collections.Counter()
        rows = {k: (after[k] - before[k]) / steps for k in after.keys() | before.keys()}
        print(f"{title}: {sum(rows.values()):.1f}" + (" a step" if len(runs) == 2 else ""))
        for key, n in sorted(rows.items(), key=lambda kv: -kv[1]):
            if n >= 0.95:
                label = key if isinstance(key, str) else f"{key[0]}  {key[1]}"
                print(f"{n:8.1f}  {label}")
        print()


if __name__ == "__main__":
    main()
