#!/usr/bin/env python3
"""Builds the workspace's tests and runs the test programs two at a time, in two lanes.

`cargo test` runs its test programs one after another. Ours are uneven: the wgpu ones spend
minutes on one core while Mesa's lavapipe compiles GPU kernels on the CPU. Here every test
program cargo builds is a job, or one job per module for the two programs made of modules
(`tests/tests/library`, `ins-cli/tests/commands`: a module is what a program used to be), in
one of two lanes:

- the lavapipe lane runs the jobs that compile GPU kernels, one after another and in the
  order LAVAPIPE gives: CubeCL keeps its tuning decisions and Mesa each kernel's LLVM code on
  disk, so a job finds what the one before it compiled (empty caches, AMD EPYC Zen 3:
  wgpu_cli 220 s after wgpu_steps; started first, cold, it ran past its 1800 s limit);
- the CPU lane runs the others, slowest first.

The lavapipe lane starts while cargo is still building, as soon as the next job in its order is
linked (the last minutes of a build are the test programs, one core's worth); the CPU lane
starts when the build is done. A lane whose own jobs are finished takes the other lane's.

Nothing is skipped: the job list is what cargo builds (`cargo test --no-run`), plus the doc
tests of the libraries that have any. Each program runs in its package's folder, as cargo runs
it. Its output is printed whole when it ends; the summary names every failure and the script
exits non-zero on any.

Usage: scripts/run_tests.py [-- ARGS FOR EVERY TEST PROGRAM, e.g. a name filter]
Environment: INS_TEST_JOBS (programs at once after the build, default 2).
"""

import json
import os
import re
import subprocess
import sys
import threading
import time

# The test modules (or programs) that run wgpu on Mesa's lavapipe, in the order their lane runs
# them. Lavapipe compiles each kernel on the CPU, and Mesa keeps them on disk: the step
# comparisons first, whose kernels the CLI's runs then find compiled (with Mesa's disk cache
# warm, one IDR step on wgpu took 164 s against 514 s cold, AMD EPYC Zen 3, when tuning still
# compiled five tiled matmuls a size; scripts/test.sh now turns tuning off, and wgpu_steps took
# 64 s cold instead of 700, fifty-eighth session). Each module keeps a process of its own, so
# that the CPU lane, once its own jobs are done, compiles the next one on the other core (the
# four library modules in one process took 2401 s there, on one core).
LAVAPIPE = ["wgpu_steps", "wgpu_render_ops", "backends", "vgg_import", "hash_grid", "wgpu_cli"]

# The modules whose tests share one wgpu device inside their process run one test at a time.
# Two test threads on one lavapipe device gave intermittently different results (wgpu_steps:
# one IDR step 3.5 % and another 0.12 % away from flex, in 2 of 5 runs, once IDR's sphere
# tracing ran its rounds on the device; 0 of 4 before it and 0 of 4 one at a time, forty-first
# session; cause not found). The CLI and the viewer drive a device from one thread. Lavapipe
# spreads each kernel over both cores anyway: wgpu_steps took 93-98 s one at a time against
# 91-99 s two at a time.
ONE_AT_A_TIME = {"wgpu_steps", "wgpu_render_ops", "backends", "vgg_import", "hash_grid"}

# The slowest CPU programs, slowest first (same machine, beside the lavapipe lane): starting
# them first keeps the last minutes from being one long program alone.
SLOWEST_FIRST = [
    "idr",  # 386 s with the notched block's volume test (nineteenth session)
    "capture_cli",
    "nerf",
    "viewer_cli",
    "report_cli",
    "stylize_cli",
    "nerf_cli",
    "siren",
    "stylize2d",
    "cpu_fallback",
]

RESULT = re.compile(r"test result: \w+\. (\d+) passed; (\d+) failed; (\d+) ignored")


def lane_of(name, label):
    # `vgg_import` names both the crate's unit tests and its wgpu integration test.
    return "lavapipe" if name in LAVAPIPE and " test " in label else "cpu"


def rank(name, label):
    order = LAVAPIPE if lane_of(name, label) == "lavapipe" else SLOWEST_FIRST
    return order.index(name) if name in order and " lib " not in label else len(order)


class Jobs:
    """The jobs cargo has built so far, per lane, and whether the build is over."""

    def __init__(self):
        self.cond = threading.Condition()
        self.pending = {"lavapipe": [], "cpu": []}
        self.built = False
        self.failed_build = False
        self.all = []
        self.started = set()  # the LAVAPIPE modules whose job has started

    def add(self, job):
        with self.cond:
            self.pending[lane_of(job[0], job[1])].append(job)
            self.all.append(job)
            self.cond.notify_all()

    def finish_build(self, ok, extra):
        with self.cond:
            for job in extra:
                self.pending[lane_of(job[0], job[1])].append(job)
                self.all.append(job)
            self.built = True
            self.failed_build = not ok
            self.cond.notify_all()

    def take(self, lane):
        """The next job for `lane`: its own, best ranked among those built; once the build is
        over, the other lane's when its own are done. None when nothing is left (or the build
        failed). While cargo builds, the lavapipe lane keeps LAVAPIPE's order: it waits for
        the next module in it rather than start a later one that would compile the same
        kernels cold."""
        other = "cpu" if lane == "lavapipe" else "lavapipe"
        with self.cond:
            while True:
                if self.failed_build:
                    return None
                for source in (lane, other) if self.built else (lane,):
                    jobs = self.pending[source]
                    if not jobs:
                        continue
                    jobs.sort(key=lambda j: rank(j[0], j[1]))
                    if source == "lavapipe" and not self.built:
                        due = next((m for m in LAVAPIPE if m not in self.started), None)
                        if due is not None and jobs[0][0] != due:
                            continue
                    job = jobs.pop(0)
                    if lane_of(job[0], job[1]) == "lavapipe":
                        self.started.add(job[0])
                    return job
                if self.built:
                    return None
                self.cond.wait()


def build(root, args, jobs):
    """Runs `cargo test --no-run`, adding each test program to `jobs` as cargo reports it.

    `--timings` leaves cargo's build profile in target/cargo-timings/: where a slow CI build
    went, per crate."""
    cmd = [
        "cargo", "test", "--release", "--workspace", "--no-run", "--timings",
        "--message-format=json-render-diagnostics",
    ]
    # An integration test runs its package's binaries (CARGO_BIN_EXE_*), but cargo links the
    # test without waiting for them (cargo#7394): such a test program is held back until every
    # binary of its package is reported built. CI once started wgpu_cli 7 minutes before
    # ins-cli was linked, and its four tests failed at once with "No such file".
    bins_missing = binaries_by_package(root)
    held = []
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, text=True)
    for line in proc.stdout:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        target = msg["target"]
        kind = target["kind"][0]
        package = os.path.dirname(msg["manifest_path"])
        if not msg.get("profile", {}).get("test"):
            if kind == "bin":
                bins_missing.get(package, set()).discard(target["name"])
                for job in [j for j in held if not bins_missing.get(j[3])]:
                    held.remove(job)
                    jobs.add(job)
            continue
        for job in program_jobs(msg["executable"], kind, target, package, args):
            if kind in ("test", "bench") and bins_missing.get(package):
                held.append(job)
            else:
                jobs.add(job)
    ok = proc.wait() == 0
    for job in held:  # the build is over: cargo built every binary it was going to
        jobs.add(job)
    extra = []
    # The doc tests of the libraries that have any (`doctest = false` marks those without):
    # cargo builds and runs them itself.
    documented = doc_tested_packages(root) if ok else []
    if documented:
        packages = [flag for p in documented for flag in ("-p", p)]
        extra.append(("doc", "doc tests",
                      ["cargo", "test", "--release", *packages, "--doc", "--", *args], root))
    jobs.finish_build(ok, extra)
    return ok


def program_jobs(executable, kind, target, package, args):
    """The jobs of one test program: the program itself, or, for an integration test made of
    modules (a folder with a `main.rs`: `tests/tests/library`, `ins-cli/tests/commands`), one
    job per module, each in a process of its own, so that a module runs in the lane its
    backend needs and shares the CPU and the wgpu device only with its own tests, as when
    every file was a program. A name filter given to the script keeps programs whole."""
    name = target["name"]
    label = f"{os.path.basename(package)} {kind} {name}"
    whole = [(name, label, [executable, *args], package)]
    if args or kind != "test" or os.path.basename(target["src_path"]) != "main.rs":
        return whole
    listing = subprocess.run([executable, "--list", "--format", "terse"], cwd=package,
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    if listing.returncode != 0:
        return whole  # it then fails where it runs, with its own message
    modules = {}
    for line in listing.stdout.splitlines():
        if line.endswith(": test"):
            test = line[: -len(": test")]
            modules.setdefault(test.split("::")[0] if "::" in test else name, []).append(test)
    one = lambda module: ["--test-threads=1"] if module in ONE_AT_A_TIME else []
    return [(module, f"{label}::{module}", [executable, "--exact", *one(module), *tests], package)
            for module, tests in sorted(modules.items())] or whole


def workspace_packages(root):
    """cargo's metadata of the workspace's own packages."""
    return json.loads(subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps"],
        cwd=root, stdout=subprocess.PIPE, check=True, text=True).stdout)["packages"]


def binaries_by_package(root):
    """Each package folder's binary target names."""
    return {os.path.dirname(p["manifest_path"]):
            {t["name"] for t in p["targets"] if "bin" in t["kind"]}
            for p in workspace_packages(root)}


def doc_tested_packages(root):
    """The workspace packages whose library runs doc tests (cargo's `doctest`, on unless
    `[lib] doctest = false`)."""
    return [p["name"] for p in workspace_packages(root)
            if any("lib" in t["kind"] and t.get("doctest") for t in p["targets"])]


def main():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    args = sys.argv[1:]
    if args[:1] == ["--"]:
        args = args[1:]
    slots = max(1, int(os.environ.get("INS_TEST_JOBS", "2")))

    started = time.monotonic()
    jobs = Jobs()
    results = []
    lock = threading.Lock()
    running = set()

    def run(job):
        name, label, argv, folder = job
        with lock:
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
                print(f"----- still running: {', '.join(running)}", flush=True)

    def worker(lane, during_build):
        if not during_build:
            with jobs.cond:
                while not jobs.built:
                    jobs.cond.wait()
        while True:
            job = jobs.take(lane)
            if job is None:
                return
            run(job)

    # One lane runs during the build (the compiler has the other core); the others join when
    # it ends.
    lanes = ["lavapipe", "cpu"] + ["cpu"] * (slots - 2)
    threads = [threading.Thread(target=worker, args=(lane, i == 0))
               for i, lane in enumerate(lanes[:slots])]
    for t in threads:
        t.start()
    build_ok = build(root, args, jobs)
    build_seconds = time.monotonic() - started
    print(f"built in {build_seconds / 60:.1f} min; running {len(jobs.all)} test programs, "
          f"{slots} at a time", flush=True)
    for t in threads:
        t.join()
    if not build_ok:
        sys.exit("the tests did not build (cargo's messages are above)")

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
    print(f"{total[0]} passed, {total[1]} failed, {total[2]} ignored in {wall / 60:.1f} min "
          f"(build {build_seconds / 60:.1f} min)")
    # A job that never reported (its worker died) is a failure too, never a silent pass.
    missing = [label for _, label, _, _ in jobs.all if label not in {r[0] for r in results}]
    failed += [f"{label} (did not run to the end)" for label in missing]
    if failed:
        print("failed: " + "; ".join(failed))
        sys.exit(1)


if __name__ == "__main__":
    main()
