# The GPU scripts' shared part, sourced from the repository root on the device machine: the log
# under $OUT, one deadline for the whole call (DEADLINE seconds from sourcing), timed stages, and
# the carried Vulkan loader and libglvnd unpacked (NVIDIA's Vulkan driver needs libGLdispatch).
OUT=${OUT:-/tmp/gpu_out}; mkdir -p "$OUT"
DEADLINE=${DEADLINE:-560}
exec > >(tee -a "$OUT/log.txt") 2>&1
t0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - t0 ))s] $*"; }
stage() { # stage NAME TIMEOUT command...: skipped when the deadline leaves under 15 s
  local name=$1 to=$2; shift 2
  local left=$(( DEADLINE - ($(date +%s) - t0) ))
  (( left < 15 )) && { stamp "SKIP $name (deadline)"; return; }
  (( to > left )) && to=$left
  stamp "BEGIN $name (timeout $to s): $*"
  local s; s=$(date +%s.%N)
  timeout -k 5 "$to" "$@"; local rc=$?
  stamp "END $name rc=$rc wall=$(python3 -c "print(round($(date +%s.%N)-$s, 2))") s"
}
unpack() { # unpack NAME: .dev/NAME.xz to /tmp/NAME, executable
  python3 -c "import lzma,shutil; shutil.copyfileobj(lzma.open('.dev/$1.xz'), open('/tmp/$1','wb'))"
  chmod +x "/tmp/$1"
}
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
nvidia-smi -L
