"""Sums CubeCL's kernel profile (CUBECL_DEBUG_OPTION=profile lines `| 1.2ms      | name | ...`,
the duration as Rust's Debug writes it, padded to 10 characters) by kernel name: the kernels
that take a GPU step's time, largest first. Exits 1 when the log has no such line, so a
format changed under it shows instead of an empty table."""
import re, sys
from collections import defaultdict
UNIT = {"s": 1e3, "ms": 1.0, "µs": 1e-3, "us": 1e-3, "ns": 1e-6}
BOILERPLATE = {"DynamicScalar", "DynamicSize", "__Lhs", "__LhsSize", "__Rhs", "__RhsSize",
               "__Acc", "__AccSize", "()"}
tot, cnt = defaultdict(float), defaultdict(int)
pat = re.compile(r"^\|\s*([0-9.]+)\s*(s|ms|µs|us|ns)\s*\|\s*(.+?)\s*$")
for line in open(sys.argv[1], errors="replace"):
    m = pat.match(line)
    if m:
        # Generic arguments every kernel of a family repeats say nothing: keep the rest.
        parts = [p for p in m.group(3).split(" | ") if p not in BOILERPLATE]
        name = " | ".join(parts)
        tot[name] += float(m.group(1)) * UNIT[m.group(2)]
        cnt[name] += 1
if not cnt:
    sys.exit(f"no profile lines in {sys.argv[1]}")
total = sum(tot.values())
print(f"total {total:.1f} ms over {sum(cnt.values())} kernel runs")
for name, t in sorted(tot.items(), key=lambda kv: -kv[1])[:25]:
    print(f"{t:10.1f} ms {cnt[name]:6d}x  {name[:300]}")
