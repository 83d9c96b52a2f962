#!/usr/bin/env python3
"""Builds the workspace's tests once, then runs the test programs two at a time.

`cargo test` runs its test programs one after another. Ours are uneven: the wgpu ones spend
minutes on one core while Mesa's lavapipe compiles GPU kernels on the CPU, and the other core
idles (measured on an AVX2-only EPYC: the suite averaged 1.4 of 2 cores, 37 minutes with cold
caches). Here every test program cargo builds is a job; the slowest known ones start first and
the rest fill whichever slot frees up, so a kernel compile overlaps the CPU tests.

Nothing is skipped: the job list is what `cargo test --no-run` reports, plus the doc tests.
Each program runs in its package's folder, as cargo runs it. Its output is printed whole when
it ends; the summary names every failure and the script exits non-zero on any.

Usage: scripts/run_tests.py [-- ARGS FOR EVERY TEST PROGRAM, e.g. a name filter]
Environment: INS_TEST_JOBS (programs at once, default 2).
"""

import json
import os
import re
import subprocess
import sys
import threading
import time

# The slowest test programs on a fresh machine (cold Mesa and CubeCL caches), slowest first:
# starting them first keeps the last minutes from being one long program alone. Measured one
# after another (`cargo test`) on an AVX2-only EPYC: wgpu_cli 691 s, vgg_import 435 s,
# backends 298 s, capture_cli 198 s, report_cli 119 s, viewer_cli 113 s, nerf 106 s, idr 82 s;
# then siren and nerf_cli (about 50 s each) before the many short ones. wgpu_steps (785 s alone
# with empty caches) starts after backends: by then lavapipe has compiled most of its kernels
# for wgpu_cli (the same small NeRF and IDR) and for backends (the same VGG sizes).
SLOWEST_FIRST = [
    "wgpu_cli",
    "vgg_import",
    "backends",
    "wgpu_steps",
    "capture_cli",
    "report_cli",
    "viewer_cli",
    "nerf",
    "idr",
    "siren",
    "nerf_cli",
]

RESULT = re.compile(r"test result: \w+\. (\d+) passed; (\d+) failed; (\d+) ignored")


def build(root, args):
    """Builds every test program; returns the jobs (name, label, argv with `args`, folder).

    `--timings` leaves cargo's build profile in target/cargo-timings/: where a slow CI build
    went, per crate."""
    cmd = [
        "cargo", "test", "--release", "--workspace", "--no-run", "--timings",
        "--message-format=json-render-diagnostics",
    ]
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, text=True)
    jobs = []
    for line in proc.stdout:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        if not msg.get("profile", {}).get("test"):
            continue
        target = msg["target"]
        kind = target["kind"][0]
        package = os.path.dirname(msg["manifest_path"])
        label = f"{os.path.basename(package)} {kind} {target['name']}"
        jobs.append((target["name"], label, [msg["executable"], *args], package))
    if proc.wait() != 0:
        sys.exit("the tests did not build (cargo's messages are above)")
    return jobs


def order(jobs):
    """Slowest known first, then the rest in cargo's order (new programs included)."""

    def rank(job):
        name, label = job[0], job[1]
        # `vgg_import` names both the crate's unit tests and its slow integration test.
        slow = name in SLOWEST_FIRST and " lib " not in label
        return SLOWEST_FIRST.index(name) if slow else len(SLOWEST_FIRST)

    return sorted(jobs, key=rank)


def main():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    args = sys.argv[1:]
    if args[:1] == ["--"]:
        args = args[1:]
    slots = int(os.environ.get("INS_TEST_JOBS", "2"))
    jobs = order(build(root, args))
    # The doc tests: cargo builds and runs them itself.
    jobs.append(("doc", "doc tests",
                 ["cargo", "test", "--release", "--workspace", "--doc", "--", *args], root))

    started = time.monotonic()
    pending = list(jobs)
    results = []
    lock = threading.Lock()
    running = set()

    def worker():
        while True:
            with lock:
                if not pending:
                    return
                name, label, argv, folder = pending.pop(0)
                running.add(label)
            t0 = time.monotonic()
            proc = subprocess.run(argv, cwd=folder, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, errors="replace")
            took = time.monotonic() - t0
            counts = [0, 0, 0]
            for m in RESULT.finditer(proc.stdout):
                counts = [c + int(g) for c, g in zip(counts, m.groups())]
            with lock:
                running.discard(label)
                results.append((label, proc.returncode, took, counts))
                elapsed = time.monotonic() - started
                print(f"\n===== {label}: exit {proc.returncode}, {took:.0f} s "
                      f"(at {elapsed / 60:.1f} min) =====", flush=True)
                print(proc.stdout, end="", flush=True)
                if running:
                    still = ", ".join(running)
                    print(f"----- still running: {still}", flush=True)

    print(f"running {len(jobs)} test programs, {slots} at a time", flush=True)
    threads = [threading.Thread(target=worker) for _ in range(slots)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()

    total = [0, 0, 0]
    failed = []
    print("\n===== summary (seconds, passed/failed/ignored) =====")
    for label, code, took, counts in sorted(results, key=lambda r: -r[2]):
        total = [a + b for a, b in zip(total, counts)]
        mark = "" if code == 0 else "   <- FAILED"
        print(f"{took:7.0f}  {counts[0]:4d}/{counts[1]}/{counts[2]}  {label}{mark}")
        if code != 0:
            failed.append(label)
    wall = time.monotonic() - started
    print(f"{total[0]} passed, {total[1]} failed, {total[2]} ignored "
          f"in {wall / 60:.1f} min")
    # A job that never reported (its worker died) is a failure too, never a silent pass.
    missing = [label for _, label, _, _ in jobs if label not in {r[0] for r in results}]
    failed += [f"{label} (did not run to the end)" for label in missing]
    if failed:
        print("failed: " + "; ".join(failed))
        sys.exit(1)


if __name__ == "__main__":
    main()
