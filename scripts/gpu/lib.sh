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
cuda_env() { # CUDA_PATH and the library path for --backend cuda: NVRTC compiles the kernels
  # against CUDA's headers. A toolkit in /usr/local/cuda serves as is; otherwise the NVIDIA
  # wheels PyTorch installed (nvidia/*/include, nvidia/*/lib) are merged into /tmp/cuda.
  if [ -f "${CUDA_PATH:-/usr/local/cuda}/include/cuda_runtime.h" ]; then
    export CUDA_PATH=${CUDA_PATH:-/usr/local/cuda}
    export LD_LIBRARY_PATH=$CUDA_PATH/lib64:${LD_LIBRARY_PATH:-}
  else
    local roots; roots=$(python3 -c "import nvidia, sys; print(' '.join(nvidia.__path__))" 2>/dev/null)
    mkdir -p /tmp/cuda/include /tmp/cuda/lib64
    for r in $roots; do
      for inc in $(find "$r" -maxdepth 3 -type d -name include); do cp -rsf "$inc"/. /tmp/cuda/include/ 2>/dev/null; done
      for lib in $(find "$r" -maxdepth 3 -type d -name lib); do LD_LIBRARY_PATH=$lib:${LD_LIBRARY_PATH:-}; done
    done
    # crt/mma.h (the tensor-core matmuls include it) is in nvidia-cuda-crt, which PyTorch does
    # not install: pack.sh packs that wheel for each CUDA 13 minor version; take NVRTC's.
    if [ ! -f /tmp/cuda/include/crt/mma.h ] && ls .gl/crt/*.whl >/dev/null 2>&1; then
      mkdir -p /tmp/cuda/include/crt
      local v whl; v=$(python3 -c "import importlib.metadata as m; print('.'.join(m.version('nvidia-cuda-nvrtc').split('.')[:2]))" 2>/dev/null)
      whl=$(ls .gl/crt/nvidia_cuda_crt-"$v".*.whl 2>/dev/null | head -1)
      [ -n "$whl" ] || whl=$(ls .gl/crt/*.whl | sort -V | tail -1)
      python3 - "$whl" <<'PY'
import sys, zipfile
z = zipfile.ZipFile(sys.argv[1])
for n in z.namelist():
    if "/include/crt/" in n:
        with open("/tmp/cuda/include/crt/" + n.split("/include/crt/", 1)[1], "wb") as f:
            f.write(z.read(n))
PY
    fi
    export CUDA_PATH=/tmp/cuda LD_LIBRARY_PATH
    # cudarc asks for libnvrtc.so by its major version's names; the wheels ship libnvrtc.so.N.
    local nvrtc; nvrtc=$(find $roots -name 'libnvrtc.so*' ! -name '*builtins*' 2>/dev/null | head -1)
    [ -n "$nvrtc" ] && ln -sf "$nvrtc" /tmp/cuda/lib64/libnvrtc.so && LD_LIBRARY_PATH=/tmp/cuda/lib64:$LD_LIBRARY_PATH
  fi
  stamp "CUDA_PATH=$CUDA_PATH cuda_runtime.h: $(ls "$CUDA_PATH"/include/cuda_runtime.h 2>&1 | head -1); crt/mma.h: $(ls "$CUDA_PATH"/include/crt/mma.h 2>&1 | head -1); nvrtc: $(ldconfig -p | grep -c nvrtc) in ldconfig, $(find ${LD_LIBRARY_PATH//:/ } -maxdepth 1 -name 'libnvrtc*' 2>/dev/null | head -3 | tr '\n' ' ')"
}
restore_vgg() { # the converted VGG-16 weights where the binary looks for them (pack.sh's .dev/vgg.*)
  [ -f .dev/vgg.meta ] || { stamp "no VGG-16 weights packed (VGG=0): stylizing stages will stop"; return; }
  read -r bpk onnx size mtime < .dev/vgg.meta
  mkdir -p "$(dirname "$onnx")"
  python3 -c "import lzma,shutil; shutil.copyfileobj(lzma.open('.dev/vgg.bpk.xz'), open('$(dirname "$onnx")/$bpk','wb'))"
  cp .dev/"${bpk%.bpk}".json "$(dirname "$onnx")/"
  truncate -s "$size" "$onnx"; touch -d "${mtime//_/ }" "$onnx"
  export INS_CACHE_DIR=$(dirname "$(dirname "$onnx")")
}
missing_rows() { # missing_rows BACKEND WORKLOAD...: those with no benchmark line in the log yet
  local backend=$1 w; shift
  sleep 1 # tee may still be writing the stage's last lines
  for w in "$@"; do
    grep -q "\"backend\":\"$backend\".*\"workload\":\"$w\"" "$OUT/log.txt" || printf '%s ' "$w"
  done
}
