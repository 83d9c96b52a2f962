"""Validates every SPIR-V module in a CubeCL compilation log with spirv-val.

Usage: python3 scripts/spirv_validate.py LOG [WORKDIR]

LOG is what a `--features spirv` build writes with CUBECL_DEBUG_LOG=LOG and
CUBECL_DEBUG_OPTION=debug: each compiled kernel's name and its SPIR-V as text. Each module is
assembled (spirv-as) and validated for Vulkan 1.3 (spirv-val), both from Debian's spirv-tools.
Why: a driver given invalid SPIR-V may crash or compute nonsense without an error (Mesa's
lavapipe crashed on CubeCL 0.11.3's shared memory; see third_party/cubecl-spirv). Prints one
line per invalid module and a count; exits 1 when any is invalid.
"""

import os
import re
import subprocess
import sys
import tempfile


def modules(log):
    """(kernel name, SPIR-V text) of each compiled kernel in the log."""
    for block in log.split("[START_KERNEL_COMPILATION]")[1:]:
        name = re.search(r"name: ([^\n]*)", block)
        text = re.search(r"```spirv\n(.*?)```", block, re.S)
        if text:
            yield (name.group(1).strip() if name else "?"), text.group(1)


def check(name, text, work, i):
    """None when the module assembles and validates, else the tools' first complaint."""
    asm, spv = os.path.join(work, f"k{i}.spvasm"), os.path.join(work, f"k{i}.spv")
    with open(asm, "w") as f:
        f.write(text)
    for cmd in (
        ["spirv-as", "--target-env", "vulkan1.3", asm, "-o", spv],
        ["spirv-val", "--target-env", "vulkan1.3", spv],
    ):
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode:
            first = (r.stderr or r.stdout).strip().splitlines()
            return f"{cmd[0]}: {first[0] if first else r.returncode} ({asm})"
    return None


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    log = open(sys.argv[1]).read()
    work = sys.argv[2] if len(sys.argv) > 2 else tempfile.mkdtemp(prefix="spirv_")
    os.makedirs(work, exist_ok=True)
    found = list(modules(log))
    if not found:
        sys.exit(f"no SPIR-V modules in {sys.argv[1]} (a WGSL build, or logging off?)")
    bad = 0
    for i, (name, text) in enumerate(found):
        problem = check(name, text, work, i)
        if problem:
            bad += 1
            print(f"INVALID {name}: {problem}")
    print(f"{len(found) - bad} of {len(found)} SPIR-V modules valid")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
