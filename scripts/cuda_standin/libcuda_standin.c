// A stand-in for NVIDIA's driver library (libcuda.so) on machines without a GPU, for
// scripts/cuda_compile_check.sh: `--backend cuda` then starts, NVRTC (the real one) compiles
// every kernel a run asks for, and this library takes each compiled module (NVRTC's CUBIN, or
// PTX where NVRTC gave none), writes it to $STANDIN_PTX_DIR, and records each launch. No
// kernel runs: device memory is host memory that kernels never write, so a run's numbers mean
// nothing, only that every kernel compiled. The device it reports is an H100's (sm_90, 132 SMs, 227 KiB of shared
// memory a block), named so that ins-core's first-kernel probe knows not to check its sum.
#define _GNU_SOURCE
#include <cuda.h>
#include <execinfo.h>
#include <link.h>
#include <stdatomic.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

static atomic_long modules, launches;
static FILE *launch_log;
// With $STANDIN_LAUNCH_LOG set, every launch, allocation, copy and sync is written there, one a
// line: what a step asks of the driver, counted without a GPU.
static void log_call(const char *fmt, ...) {
  const char *path = getenv("STANDIN_LAUNCH_LOG");
  if (path && !launch_log) launch_log = fopen(path, "a");
  if (!launch_log) return;
  va_list args;
  va_start(args, fmt);
  vfprintf(launch_log, fmt, args);
  va_end(args);
}

// With $STANDIN_BACKTRACE also set, each launch whose kernel name contains its value (":"
// matches every one) is followed by the return addresses on its stack that lie in the program
// itself, one "  bt OFFSET" line each (hex, from the program's load address), innermost first:
// scripts/cuda_standin/launch_sites.py names them (addr2line) to tell which line of the
// workspace asked for each kernel.
static uintptr_t exe_bias, exe_lo = UINTPTR_MAX, exe_hi;
static int first_object(struct dl_phdr_info *info, size_t size, void *data) {
  (void)size; (void)data;
  exe_bias = info->dlpi_addr;
  for (int i = 0; i < info->dlpi_phnum; i++)
    if (info->dlpi_phdr[i].p_type == PT_LOAD && (info->dlpi_phdr[i].p_flags & PF_X)) {
      uintptr_t lo = exe_bias + info->dlpi_phdr[i].p_vaddr;
      if (lo < exe_lo) exe_lo = lo;
      if (lo + info->dlpi_phdr[i].p_memsz > exe_hi) exe_hi = lo + info->dlpi_phdr[i].p_memsz;
    }
  return 1; // the program is the first object listed
}
static void log_backtrace(const char *kernel) {
  const char *pattern = getenv("STANDIN_BACKTRACE");
  if (!pattern || !launch_log || !strstr(kernel, pattern)) return;
  if (!exe_hi) dl_iterate_phdr(first_object, NULL);
  void *frames[64];
  int n = backtrace(frames, 64);
  for (int i = 0; i < n; i++) {
    uintptr_t a = (uintptr_t)frames[i];
    if (a >= exe_lo && a < exe_hi) fprintf(launch_log, "  bt %lx\n", (unsigned long)(a - exe_bias));
  }
}

static void *device_bytes(size_t size) {
  // Lazily backed: a memory pool's large pages cost nothing until written.
  void *p = mmap(NULL, size ? size : 1, PROT_READ | PROT_WRITE,
                 MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
  return p == MAP_FAILED ? NULL : p;
}


CUresult cuInit(unsigned int flags) { (void)flags; return CUDA_SUCCESS; }
CUresult cuDriverGetVersion(int *v) { *v = 13000; return CUDA_SUCCESS; }
CUresult cuDeviceGetCount(int *n) { *n = 1; return CUDA_SUCCESS; }
CUresult cuDeviceGet(CUdevice *d, int ordinal) {
  if (ordinal != 0) return CUDA_ERROR_INVALID_DEVICE;
  *d = 0;
  return CUDA_SUCCESS;
}
CUresult cuDeviceGetName(char *name, int len, CUdevice d) {
  (void)d;
  snprintf(name, len, "INS-rs CUDA stand-in (H100-like, compiles only)");
  return CUDA_SUCCESS;
}
CUresult cuDeviceTotalMem(size_t *bytes, CUdevice d) {
  (void)d;
  *bytes = 80ull << 30;
  return CUDA_SUCCESS;
}
CUresult cuMemGetInfo(size_t *free_bytes, size_t *total) {
  *free_bytes = 79ull << 30;
  *total = 80ull << 30;
  return CUDA_SUCCESS;
}
CUresult cuDeviceGetPCIBusId(char *id, int len, CUdevice d) {
  (void)d;
  snprintf(id, len, "0000:00:00.0");
  return CUDA_SUCCESS;
}
CUresult cuDeviceGetUuid(CUuuid *uuid, CUdevice d) {
  (void)d;
  memset(uuid, 0x5a, sizeof *uuid);
  return CUDA_SUCCESS;
}
CUresult cuDeviceGetAttribute(int *v, CUdevice_attribute a, CUdevice d) {
  (void)d;
  switch (a) {
  case CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MAJOR: *v = 9; break;
  case CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MINOR: *v = 0; break;
  case CU_DEVICE_ATTRIBUTE_WARP_SIZE: *v = 32; break;
  case CU_DEVICE_ATTRIBUTE_MAX_SHARED_MEMORY_PER_BLOCK_OPTIN: *v = 232448; break;
  case CU_DEVICE_ATTRIBUTE_MAX_SHARED_MEMORY_PER_BLOCK: *v = 49152; break;
  case CU_DEVICE_ATTRIBUTE_MAX_SHARED_MEMORY_PER_MULTIPROCESSOR: *v = 233472; break;
  case CU_DEVICE_ATTRIBUTE_MAX_THREADS_PER_BLOCK: *v = 1024; break;
  case CU_DEVICE_ATTRIBUTE_MAX_THREADS_PER_MULTIPROCESSOR: *v = 2048; break;
  case CU_DEVICE_ATTRIBUTE_MAX_BLOCK_DIM_X: *v = 1024; break;
  case CU_DEVICE_ATTRIBUTE_MAX_BLOCK_DIM_Y: *v = 1024; break;
  case CU_DEVICE_ATTRIBUTE_MAX_BLOCK_DIM_Z: *v = 64; break;
  case CU_DEVICE_ATTRIBUTE_MAX_GRID_DIM_X: *v = 2147483647; break;
  case CU_DEVICE_ATTRIBUTE_MAX_GRID_DIM_Y: *v = 65535; break;
  case CU_DEVICE_ATTRIBUTE_MAX_GRID_DIM_Z: *v = 65535; break;
  case CU_DEVICE_ATTRIBUTE_MULTIPROCESSOR_COUNT: *v = 132; break;
  case CU_DEVICE_ATTRIBUTE_MAX_REGISTERS_PER_BLOCK: *v = 65536; break;
  case CU_DEVICE_ATTRIBUTE_L2_CACHE_SIZE: *v = 50 << 20; break;
  case CU_DEVICE_ATTRIBUTE_CLOCK_RATE: *v = 1980000; break;
  case CU_DEVICE_ATTRIBUTE_MEMORY_POOLS_SUPPORTED: *v = 1; break;
  case CU_DEVICE_ATTRIBUTE_UNIFIED_ADDRESSING: *v = 1; break;
  default: *v = 0;
  }
  return CUDA_SUCCESS;
}

// Contexts, streams and events are tokens; everything happens at once, in order.
static int token;
CUresult cuDevicePrimaryCtxRetain(CUcontext *c, CUdevice d) { (void)d; *c = (CUcontext)&token; return CUDA_SUCCESS; }
CUresult cuDevicePrimaryCtxRelease(CUdevice d) { (void)d; return CUDA_SUCCESS; }
CUresult cuCtxSetCurrent(CUcontext c) { (void)c; return CUDA_SUCCESS; }
CUresult cuCtxGetCurrent(CUcontext *c) { *c = (CUcontext)&token; return CUDA_SUCCESS; }
CUresult cuCtxSynchronize(void) { log_call("sync context\n"); return CUDA_SUCCESS; }
CUresult cuCtxGetStreamPriorityRange(int *least, int *greatest) { *least = 0; *greatest = -5; return CUDA_SUCCESS; }
CUresult cuStreamCreate(CUstream *s, unsigned int f) { (void)f; *s = (CUstream)malloc(8); return CUDA_SUCCESS; }
CUresult cuStreamCreateWithPriority(CUstream *s, unsigned int f, int p) { (void)p; return cuStreamCreate(s, f); }
CUresult cuStreamDestroy(CUstream s) { (void)s; return CUDA_SUCCESS; }
CUresult cuStreamSynchronize(CUstream s) { (void)s; log_call("sync stream\n"); return CUDA_SUCCESS; }
CUresult cuStreamQuery(CUstream s) { (void)s; return CUDA_SUCCESS; }
CUresult cuStreamWaitEvent(CUstream s, CUevent e, unsigned int f) { (void)s; (void)e; (void)f; return CUDA_SUCCESS; }
// An event keeps the launch count at its record; the time between two is 5 µs a launch, so
// CubeCL's timing loops (autotune, its launch-overhead probe) see time pass and end.
CUresult cuEventCreate(CUevent *e, unsigned int f) { (void)f; *e = (CUevent)calloc(1, sizeof(long)); return CUDA_SUCCESS; }
CUresult cuEventRecord(CUevent e, CUstream s) { (void)s; *(long *)e = launches; return CUDA_SUCCESS; }
CUresult cuEventRecordWithFlags(CUevent e, CUstream s, unsigned int f) { (void)f; return cuEventRecord(e, s); }
CUresult cuEventSynchronize(CUevent e) { (void)e; log_call("sync event\n"); return CUDA_SUCCESS; }
CUresult cuEventQuery(CUevent e) { (void)e; return CUDA_SUCCESS; }
CUresult cuEventDestroy(CUevent e) { free(e); return CUDA_SUCCESS; }
CUresult cuEventElapsedTime(float *ms, CUevent a, CUevent b) {
  *ms = 0.001f + 0.005f * (float)(*(long *)b - *(long *)a);
  return CUDA_SUCCESS;
}
// CUDA graphs: not offered, so CubeCL launches kernel by kernel.
CUresult cuStreamBeginCapture(CUstream s, CUstreamCaptureMode m) { (void)s; (void)m; return CUDA_ERROR_NOT_SUPPORTED; }

// Device memory is host memory (unified addresses), so copies are plain copies.
CUresult cuMemAlloc(CUdeviceptr *p, size_t n) { log_call("alloc %zu\n", n); void *m = device_bytes(n); if (!m) return CUDA_ERROR_OUT_OF_MEMORY; *p = (CUdeviceptr)m; return CUDA_SUCCESS; }
CUresult cuMemAllocAsync(CUdeviceptr *p, size_t n, CUstream s) { (void)s; return cuMemAlloc(p, n); }
CUresult cuMemFree(CUdeviceptr p) { (void)p; log_call("free\n"); return CUDA_SUCCESS; } // pages stay mapped: sizes are not kept
CUresult cuMemFreeAsync(CUdeviceptr p, CUstream s) { (void)s; return cuMemFree(p); }
CUresult cuMemAllocHost(void **p, size_t n) { log_call("alloc_host %zu\n", n); *p = device_bytes(n); return *p ? CUDA_SUCCESS : CUDA_ERROR_OUT_OF_MEMORY; }
CUresult cuMemHostAlloc(void **p, size_t n, unsigned int f) { (void)f; return cuMemAllocHost(p, n); }
CUresult cuMemFreeHost(void *p) { (void)p; log_call("free_host\n"); return CUDA_SUCCESS; }
CUresult cuMemcpyHtoD(CUdeviceptr d, const void *h, size_t n) { log_call("htod %zu\n", n); memcpy((void *)d, h, n); return CUDA_SUCCESS; }
CUresult cuMemcpyDtoH(void *h, CUdeviceptr d, size_t n) { log_call("dtoh %zu\n", n); memcpy(h, (void *)d, n); return CUDA_SUCCESS; }
CUresult cuMemcpyDtoD(CUdeviceptr a, CUdeviceptr b, size_t n) { memmove((void *)a, (void *)b, n); return CUDA_SUCCESS; }
CUresult cuMemcpyHtoDAsync(CUdeviceptr d, const void *h, size_t n, CUstream s) { (void)s; return cuMemcpyHtoD(d, h, n); }
CUresult cuMemcpyDtoHAsync(void *h, CUdeviceptr d, size_t n, CUstream s) { (void)s; return cuMemcpyDtoH(h, d, n); }
CUresult cuMemcpyDtoDAsync(CUdeviceptr a, CUdeviceptr b, size_t n, CUstream s) { (void)s; return cuMemcpyDtoD(a, b, n); }
static const char *base(CUmemorytype t, const void *host, CUdeviceptr dev) {
  return t == CU_MEMORYTYPE_HOST ? (const char *)host : (const char *)dev;
}
CUresult cuMemcpy2DAsync(const CUDA_MEMCPY2D *c, CUstream s) {
  (void)s;
  log_call("copy2d %s %zu\n", c->dstMemoryType == CU_MEMORYTYPE_HOST ? "dtoh" : "htod",
           (size_t)(c->WidthInBytes * c->Height));
  const char *src = base(c->srcMemoryType, c->srcHost, c->srcDevice);
  char *dst = (char *)base(c->dstMemoryType, c->dstHost, c->dstDevice);
  for (size_t y = 0; y < c->Height; y++)
    memmove(dst + (c->dstY + y) * c->dstPitch + c->dstXInBytes,
            src + (c->srcY + y) * c->srcPitch + c->srcXInBytes, c->WidthInBytes);
  return CUDA_SUCCESS;
}
CUresult cuMemsetD8Async(CUdeviceptr d, unsigned char v, size_t n, CUstream s) { (void)s; memset((void *)d, v, n); return CUDA_SUCCESS; }
CUresult cuMemsetD32Async(CUdeviceptr d, unsigned int v, size_t n, CUstream s) {
  (void)s;
  for (size_t i = 0; i < n; i++) ((unsigned int *)d)[i] = v;
  return CUDA_SUCCESS;
}

// Modules: what NVRTC produced, kept for checking: PTX text (for ptxas), or the CUBIN NVRTC
// assembled itself (an ELF64 image, written whole: it ends where its program or section
// headers end, whichever is last).
struct function { char name[512]; };
CUresult cuModuleLoadData(CUmodule *m, const void *image) {
  long id = atomic_fetch_add(&modules, 1);
  const char *dir = getenv("STANDIN_PTX_DIR");
  if (dir && *dir) {
    const unsigned char *b = image;
    int elf = b[0] == 0x7f && b[1] == 'E' && b[2] == 'L' && b[3] == 'F';
    char path[4096];
    snprintf(path, sizeof path, "%s/%06ld.%s", dir, id, elf ? "cubin" : "ptx");
    FILE *f = fopen(path, "w");
    if (!f) return CUDA_ERROR_FILE_NOT_FOUND;
    if (elf) {
      uint64_t phoff, shoff; uint16_t phentsize, phnum, shentsize, shnum;
      memcpy(&phoff, b + 0x20, 8);
      memcpy(&shoff, b + 0x28, 8);
      memcpy(&phentsize, b + 0x36, 2);
      memcpy(&phnum, b + 0x38, 2);
      memcpy(&shentsize, b + 0x3a, 2);
      memcpy(&shnum, b + 0x3c, 2);
      uint64_t ph_end = phoff + (uint64_t)phentsize * phnum, sh_end = shoff + (uint64_t)shentsize * shnum;
      fwrite(b, 1, ph_end > sh_end ? ph_end : sh_end, f);
    } else {
      fputs((const char *)image, f);
    }
    fclose(f);
  }
  *m = (CUmodule)(intptr_t)(id + 1);
  return CUDA_SUCCESS;
}
CUresult cuModuleUnload(CUmodule m) { (void)m; return CUDA_SUCCESS; }
CUresult cuModuleGetFunction(CUfunction *f, CUmodule m, const char *name) {
  struct function *fn = malloc(sizeof *fn);
  snprintf(fn->name, sizeof fn->name, "%ld:%s", (long)(intptr_t)m - 1, name);
  *f = (CUfunction)fn;
  return CUDA_SUCCESS;
}
CUresult cuFuncSetAttribute(CUfunction f, CUfunction_attribute a, int v) { (void)f; (void)a; (void)v; return CUDA_SUCCESS; }
CUresult cuFuncGetAttribute(int *v, CUfunction_attribute a, CUfunction f) { (void)a; (void)f; *v = 0; return CUDA_SUCCESS; }
CUresult cuLaunchKernel(CUfunction f, unsigned gx, unsigned gy, unsigned gz, unsigned bx, unsigned by,
                        unsigned bz, unsigned shared, CUstream s, void **params, void **extra) {
  (void)s; (void)params; (void)extra;
  atomic_fetch_add(&launches, 1);
  log_call("launch %s grid %u %u %u block %u %u %u shared %u\n", ((struct function *)f)->name,
           gx, gy, gz, bx, by, bz, shared);
  log_backtrace(((struct function *)f)->name);
  if ((unsigned long long)bx * by * bz > 1024 || bz > 64 || gy > 65535 || gz > 65535 || shared > 232448)
    return CUDA_ERROR_INVALID_VALUE; // what the real driver refuses
  return CUDA_SUCCESS;
}

CUresult cuGetErrorString(CUresult e, const char **s) { (void)e; *s = "CUDA stand-in error"; return CUDA_SUCCESS; }
CUresult cuGetErrorName(CUresult e, const char **s) { (void)e; *s = "CUDA_ERROR_STANDIN"; return CUDA_SUCCESS; }

// Tensor maps (TMA) describe a tensor to the hardware; no kernel reads them here.
CUresult cuTensorMapEncodeTiled(CUtensorMap *m, CUtensorMapDataType t, cuuint32_t rank, void *g,
                                const cuuint64_t *dims, const cuuint64_t *strides, const cuuint32_t *box,
                                const cuuint32_t *es, CUtensorMapInterleave i, CUtensorMapSwizzle s,
                                CUtensorMapL2promotion l, CUtensorMapFloatOOBfill f) {
  (void)t; (void)rank; (void)g; (void)dims; (void)strides; (void)box; (void)es; (void)i; (void)s; (void)l; (void)f;
  memset(m, 0, sizeof *m);
  return CUDA_SUCCESS;
}
CUresult cuTensorMapEncodeIm2col(CUtensorMap *m, CUtensorMapDataType t, cuuint32_t rank, void *g,
                                 const cuuint64_t *dims, const cuuint64_t *strides, const int *lo,
                                 const int *hi, cuuint32_t ch, cuuint32_t px, const cuuint32_t *es,
                                 CUtensorMapInterleave i, CUtensorMapSwizzle s, CUtensorMapL2promotion l,
                                 CUtensorMapFloatOOBfill f) {
  (void)t; (void)rank; (void)g; (void)dims; (void)strides; (void)lo; (void)hi; (void)ch; (void)px;
  (void)es; (void)i; (void)s; (void)l; (void)f;
  memset(m, 0, sizeof *m);
  return CUDA_SUCCESS;
}
CUresult cuTensorMapEncodeIm2colWide(CUtensorMap *m, CUtensorMapDataType t, cuuint32_t rank, void *g,
                                     const cuuint64_t *dims, const cuuint64_t *strides, int lo, int hi,
                                     cuuint32_t ch, cuuint32_t px, const cuuint32_t *es,
                                     CUtensorMapInterleave i, CUtensorMapIm2ColWideMode w, CUtensorMapSwizzle s,
                                     CUtensorMapL2promotion l, CUtensorMapFloatOOBfill f) {
  (void)t; (void)rank; (void)g; (void)dims; (void)strides; (void)lo; (void)hi; (void)ch; (void)px;
  (void)es; (void)i; (void)w; (void)s; (void)l; (void)f;
  memset(m, 0, sizeof *m);
  return CUDA_SUCCESS;
}
