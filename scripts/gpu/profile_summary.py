"""Sums CubeCL's kernel profile (CUBECL_DEBUG_OPTION=profile lines `| 1.2ms | name: ...`) by
kernel name: the kernels that take a GPU step's time, largest first."""
import re, sys
from collections import defaultdict
UNIT = {"s": 1e3, "ms": 1.0, "µs": 1e-3, "us": 1e-3, "ns": 1e-6}
tot, cnt = defaultdict(float), defaultdict(int)
pat = re.compile(r"^\| ([0-9.]+)(s|ms|µs|us|ns) \| ([^:{]+(?:::[^:{]+)*)")
for line in open(sys.argv[1], errors="replace"):
    m = pat.match(line)
    if m:
        name = m.group(3).strip()
        tot[name] += float(m.group(1)) * UNIT[m.group(2)]
        cnt[name] += 1
total = sum(tot.values())
print(f"total {total:.1f} ms over {sum(cnt.values())} kernel runs")
for name, t in sorted(tot.items(), key=lambda kv: -kv[1])[:25]:
    print(f"{t:10.1f} ms {cnt[name]:6d}x  {name[:150]}")
