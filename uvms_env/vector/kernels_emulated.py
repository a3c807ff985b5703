"""The CUDA kernel source of ``kernels.cuda_source``, compiled for the host CPU.

The GPU backend's kernel is compiled unchanged by the host C++ compiler, with
``__device__``/``__global__`` defined away and a loop over the environments (OpenMP
threads) standing in for the grid, so that the source and everything the backend does
around it (``VectorEnv(backend="cuda", device="cpu")``) are tested wherever the CPU
backend is (docs/batched.md, "Tested without a GPU"). It is an emulation for tests and
debugging, not a fast path: the CPU backend's SIMD lanes are several times faster.

May import: numpy, casadi, ``uvms_env.dynamics.compiled`` and ``uvms_env.vector.kernels``.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import tempfile
from functools import cache
from pathlib import Path
from typing import Any

import casadi as cs
import numpy as np

from uvms_env.dynamics.compiled import CXX_COMPILERS, _cpu_identity, cache_dir, find_compiler
from uvms_env.vector.kernels import (
    DTYPES,
    Refinement,
    Signature,
    batch_entry,
    check_inputs,
    check_outputs,
    cuda_source,
    pointers,
)

# No -march=native (no fused multiply-adds) and no fast maths: plain IEEE arithmetic, as
# the CPU backend's float64. -O0: the N = 2 period step compiles in ~3 s instead of ~14 s
# at -O2, and an emulation is for tests, not speed.
HOST_FLAGS = ("-O0", "-std=c++17", "-fopenmp", "-fPIC", "-shared", "-w")

# CUDA's names for what the host build provides: device qualifiers vanish, the built-in
# thread indices are per-host-thread variables set by the launch loop below.
_PRELUDE = """#include <math.h>
#include <omp.h>
#define __device__
#define __global__
struct uvms_index { long x; };
static thread_local uvms_index blockIdx, threadIdx, blockDim;
"""
_LAUNCH = """
extern "C" void uvms_host_launch(const casadi_real* const* in, casadi_real* const* out,
                                 long k, int threads) {
  #pragma omp parallel for num_threads(threads) schedule(static)
  for (long e = 0; e < k; ++e) {
    blockDim.x = 1; threadIdx.x = 0; blockIdx.x = e;
    uvms_batch_kernel(in, out, k);
  }
}
"""


@cache
def _build(source: str, name: str, dtype: str) -> ctypes.CDLL:
    cxx = find_compiler(CXX_COMPILERS)
    if cxx is None:
        raise RuntimeError("the emulated CUDA backend needs a C++ compiler (g++ or clang++)")
    code = _PRELUDE + source + _LAUNCH
    key = hashlib.sha256(
        (code + " ".join(HOST_FLAGS) + cs.__version__).encode() + _cpu_identity()
    ).hexdigest()[:16]
    lib = cache_dir() / f"{name}_cudahost_{dtype}_{key}.so"
    if not lib.exists():
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp) / "kernel.cpp"
            src.write_text(code)
            part = lib.with_suffix(f".{os.getpid()}.part")
            subprocess.run([cxx, *HOST_FLAGS, str(src), "-o", str(part), "-lm"], check=True)
            part.replace(lib)  # atomic: parallel workers never load a half-written library
    return ctypes.CDLL(str(lib))


class EmulatedCudaFunction:
    """``CudaBatchedFunction``'s interface and kernel source, run on the host: inputs and
    outputs are arrays of ``xp`` in the (nnz_i, K) layout; with ``refine`` one more output
    (1, K) carries the error-control status.

    ``xp``: the array namespace of the emulated device, numpy. Tests put a CuPy stand-in
    there (arrays that refuse implicit conversion to numpy) to check the backend's array
    code as CuPy would run it; the kernel reaches such arrays' memory through DLPack, as
    the GPU kernel reaches device memory through its pointers."""

    xp: Any = np

    def __init__(
        self,
        fn: cs.Function,
        dtype: str = "float64",
        refine: Refinement | None = None,
        threads: int = 1,
    ) -> None:
        if dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {dtype!r}")
        self.dtype = dtype
        self.np_dtype = DTYPES[dtype][1]
        self.threads = int(threads)
        source, self.signature = cuda_source(fn, DTYPES[dtype][0], refine)
        self.nnz_out = self.signature.nnz_out + ((1,) if refine else ())
        self._call = batch_entry(_build(source, self.signature.name, dtype).uvms_host_launch, None)

    def padded(self, k: int) -> int:
        return k

    def __call__(self, inputs: list, out: list | None = None) -> list:
        arrays = [_memory(a) for a in inputs]
        k = check_inputs(self.signature, arrays, self.dtype)
        if out is None:
            out = [self.xp.empty((nnz, k), self.np_dtype) for nnz in self.nnz_out]
        written = [_memory(a) for a in out]
        check_outputs(self.nnz_out, written, k, self.dtype)
        self._call(pointers(arrays), pointers(written), k, self.threads)
        return out


def _memory(a: Any) -> np.ndarray:
    """A host view of ``a``'s memory: numpy arrays as they are, other arrays of the emulated
    device through DLPack (no copy, no implicit conversion)."""
    return np.asarray(a) if isinstance(a, np.ndarray | list) else np.from_dlpack(a)


__all__ = ["EmulatedCudaFunction", "Signature"]
