"""Batched evaluation of a CasADi function: one generated C source, compiled for CPU lanes
and threads or as a GPU kernel, cached on disk.

The function is generated as C once (``casadi.CodeGenerator``, as for the single
environment's libraries) and wrapped, not rewritten:

CPU: ``casadi_real`` a bundle of SIMD lanes (``lanes.hpp``), OpenMP threads over blocks of
lanes; CUDA: ``kernels_cuda`` (both targets: docs/batched.md).

Layout (both targets): input and output ``i`` of the function is a C-contiguous array of
shape (nnz_i, K): the environment index innermost, so that a SIMD lane block (CPU) or a
GPU warp reads consecutive addresses. K is padded to a multiple of the lane count by the
caller (``BatchedFunction.padded``).

No hand-written C++ or CUDA library could be used instead: the physics is CasADi's
generated code and must stay the single source of truth (docs/batched.md: the single
simulator's C for every target); this module only adds the loops around it.

May import: numpy, casadi, ``uvms_env.dynamics.compiled`` (cache folder, CPU identity,
the announced build) and ``uvms_env.dynamics.split_source`` (the cut into parallel units).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import casadi as cs
import numpy as np

from uvms_env.dynamics.compiled import (
    CXX_COMPILERS,
    _cpu_identity,
    build_library,
    cache_dir,
    find_compiler,
    generated_source,
)
from uvms_env.dynamics.split_source import cut_long_functions, default_units, translation_units

HERE = Path(__file__).parent
CXXFLAGS = ("-O3", "-march=native", "-fno-math-errno", "-fopenmp", "-fPIC", "-shared")
DTYPES = {"float64": ("double", np.float64), "float32": ("float", np.float32)}
# glibc's vector maths (libmvec) entry points: (x86 ISA letter, width, suffix).
_MVEC_ISA = {"avx512f": "e", "avx2": "d", "sse2": "b"}

# Registers one block may use (every architecture since compute capability 3.0).
REGISTERS_PER_BLOCK = 65536

# Threads per block. Registers x BLOCK must fit a block's 65,536 (``kernels_check``: the
# period step takes 255 registers per thread, the most there is).
BLOCK = 128
# What the backend asks NVRTC for through CuPy's RawModule (CuPy adds -ftz=true and the
# architecture: ``kernels_check.nvrtc_options``).
NVRTC_OPTIONS = ("-std=c++17",)


@dataclass(frozen=True)
class Signature:
    """What the wrappers need to know about the generated function."""

    name: str
    nnz_in: tuple[int, ...]
    nnz_out: tuple[int, ...]
    sz_arg: int
    sz_res: int
    sz_iw: int
    sz_w: int

    @staticmethod
    def of(fn: cs.Function) -> Signature:
        return Signature(
            fn.name(),
            tuple(fn.nnz_in(i) for i in range(fn.n_in())),
            tuple(fn.nnz_out(i) for i in range(fn.n_out())),
            fn.sz_arg(),
            fn.sz_res(),
            fn.sz_iw(),
            fn.sz_w(),
        )


def available_cores() -> int:
    """The cores this process may run on (its affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def cpu_features() -> set[str]:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def default_lanes(dtype: str) -> int:
    """Lanes of the widest vector unit this CPU has for ``dtype`` (1 off x86-64)."""
    flags = cpu_features()
    bits = 512 if "avx512f" in flags else 256 if "avx2" in flags else 128
    if platform.machine() not in ("x86_64", "AMD64"):
        return 1
    return bits // (64 if dtype == "float64" else 32)


def _mvec_defines(dtype: str, lanes: int) -> list[str]:
    """-D flags naming libmvec's sin/cos/tan for this width, or [] (lane-by-lane maths)."""
    flags = cpu_features()
    bits = lanes * (64 if dtype == "float64" else 32)
    isa = {512: "avx512f", 256: "avx2", 128: "sse2"}.get(bits)
    if lanes == 1 or isa is None or isa not in flags or platform.system() != "Linux":
        return []
    letter, suffix = _MVEC_ISA[isa], "" if dtype == "float64" else "f"
    return [f"-DUVMS_{f.upper()}=_ZGV{letter}N{lanes}v_{f}{suffix}" for f in ("sin", "cos", "tan")]


def _cpu_driver(sig: Signature, lanes: int) -> str:
    """The batch loop around the generated function (appended to its source)."""
    n_in, n_out = len(sig.nnz_in), len(sig.nnz_out)
    nnz_in = ", ".join(map(str, sig.nnz_in))
    nnz_out = ", ".join(map(str, sig.nnz_out))
    return f"""
// Batch driver: K environments, input/output i laid out (nnz_i, K), K % {lanes} == 0.
#include <omp.h>
#include <string.h>
#if defined(UVMS_FLUSH_SUBNORMALS) && defined(__SSE__)
#include <xmmintrin.h>
#define UVMS_FTZ_BEGIN const unsigned int uvms_csr = _mm_getcsr(); _mm_setcsr(uvms_csr | 0x8040);
#define UVMS_FTZ_END _mm_setcsr(uvms_csr);
#else
#define UVMS_FTZ_BEGIN
#define UVMS_FTZ_END
#endif
static const long uvms_nnz_in[{n_in}] = {{{nnz_in}}};
static const long uvms_nnz_out[{n_out}] = {{{nnz_out}}};
extern "C" int uvms_batch(const lane_t* const* in, lane_t* const* out, long k, int threads) {{
  const long blocks = k / {lanes};
  int fail = 0;
  #pragma omp parallel num_threads(threads) reduction(|:fail)
  {{
    UVMS_FTZ_BEGIN  // per thread, restored below: the calling thread runs numpy after us
    vreal in_buf[{sum(sig.nnz_in) + 1}], out_buf[{sum(sig.nnz_out) + 1}];
    vreal* w = new vreal[{sig.sz_w + 1}];
    casadi_int iw[{sig.sz_iw + 1}];
    const vreal* arg[{max(sig.sz_arg, n_in)}];
    vreal* res[{max(sig.sz_res, n_out)}];
    #pragma omp for schedule(static)
    for (long b = 0; b < blocks; ++b) {{
      const long lane0 = b * {lanes};
      vreal* p = in_buf;
      for (int i = 0; i < {n_in}; ++i) {{
        for (long j = 0; j < uvms_nnz_in[i]; ++j)
          memcpy(&p[j], in[i] + j * k + lane0, sizeof(vreal));
        arg[i] = p;
        p += uvms_nnz_in[i];
      }}
      vreal* q = out_buf;
      for (int i = 0; i < {n_out}; ++i) {{ res[i] = q; q += uvms_nnz_out[i]; }}
      fail |= {sig.name}(arg, res, iw, w, 0);
      q = out_buf;
      for (int i = 0; i < {n_out}; ++i) {{
        for (long j = 0; j < uvms_nnz_out[i]; ++j)
          memcpy(out[i] + j * k + lane0, &q[j], sizeof(vreal));
        q += uvms_nnz_out[i];
      }}
    }}
    delete[] w;
    UVMS_FTZ_END
  }}
  return fail;
}}
"""


def check_inputs(sig: Signature, inputs: list, dtype: str) -> int:
    """K, after checking that ``inputs`` are ``sig``'s, each a C-contiguous (nnz_i, K)
    array of ``dtype`` (numpy or CuPy); ValueError naming the input otherwise."""
    if len(inputs) != len(sig.nnz_in):
        raise ValueError(f"{sig.name} takes {len(sig.nnz_in)} inputs, got {len(inputs)}")
    k = inputs[0].shape[1]
    for i, (a, nnz) in enumerate(zip(inputs, sig.nnz_in, strict=True)):
        if a.shape != (nnz, k) or a.dtype != DTYPES[dtype][1] or not a.flags.c_contiguous:
            raise ValueError(
                f"input {i} of {sig.name} must be a C-contiguous {dtype} array of shape "
                f"({nnz}, {k}), got {a.dtype} {a.shape}"
            )
    return k


def check_outputs(nnz_out: tuple[int, ...], out: list, k: int, dtype: str) -> None:
    """ValueError unless each of ``out`` is a C-contiguous (nnz_i, K) array of ``dtype``:
    the kernels write them as such, whatever they are."""
    if len(out) != len(nnz_out):
        raise ValueError(f"{len(nnz_out)} outputs expected, got {len(out)}")
    for i, (a, nnz) in enumerate(zip(out, nnz_out, strict=True)):
        if a.shape != (nnz, k) or a.dtype != DTYPES[dtype][1] or not a.flags.c_contiguous:
            raise ValueError(
                f"output {i} must be a C-contiguous {dtype} array of shape ({nnz}, {k}), "
                f"got {a.dtype} {a.shape}"
            )


def batch_entry(entry: ctypes._CFuncPtr, restype: type | None) -> ctypes._CFuncPtr:
    """A compiled batch loop's C entry point, typed: (const real** in, real** out, long k,
    int threads)."""
    entry.restype = restype
    entry.argtypes = [
        ctypes.POINTER(ctypes.c_void_p),
        ctypes.POINTER(ctypes.c_void_p),
        ctypes.c_long,
        ctypes.c_int,
    ]
    return entry


#: Argument lists whose addresses a ``BatchedFunction`` keeps (the oldest goes first).
ADDRESS_LISTS = 8


def pointers(arrays: list[np.ndarray]) -> ctypes.Array:
    """The data addresses of ``arrays``, as the batch loops take them."""
    return (ctypes.c_void_p * len(arrays))(*[a.ctypes.data for a in arrays])


class BatchedFunction:
    """``fn`` evaluated on K environments per call (CPU lanes and threads).

    ``outputs = bf(inputs, threads)``: ``inputs`` is a list of (nnz_i, K) arrays of the
    build's dtype, C-contiguous; outputs are written to preallocated arrays (``out=``)
    or new ones. K must be a multiple of ``lanes`` (``padded(K)``)."""

    def __init__(
        self,
        fn: cs.Function,
        dtype: str = "float64",
        lanes: int | None = None,
        source: str | None = None,
    ):
        """``source``: the C that defines ``fn`` in CasADi's calling convention, where CasADi
        cannot generate it (a compiled library's entry point written around generated
        functions, e.g. ``nmpc_expert.ocp``'s); None: CasADi's code of ``fn``."""
        if dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {dtype!r}")
        self.signature = Signature.of(fn)
        self.dtype = dtype
        self.np_dtype = DTYPES[dtype][1]
        self.lanes = default_lanes(dtype) if lanes is None else int(lanes)
        if self.lanes not in (1, 2, 4, 8, 16):
            raise ValueError(f"lanes must be 1, 2, 4, 8 or 16, got {lanes}")
        code = generated_source(fn) if source is None else source
        self._lib = _build_cpu(code, self.signature, dtype, self.lanes)
        self._call = batch_entry(self._lib.uvms_batch, ctypes.c_int)
        # the addresses of the argument lists seen last, by the arrays' identities: hot
        # paths pass the same buffers every call, and reading 20-30 addresses costs more
        # than the kernel of a small batch. Each entry holds its arrays, so that an
        # identity stays theirs while it is a key.
        self._addresses: dict[tuple[int, ...], tuple[list, ctypes.Array]] = {}

    def _pointers(self, arrays: list[np.ndarray]) -> ctypes.Array:
        key = tuple(map(id, arrays))
        hit = self._addresses.get(key)
        if hit is None:
            if len(self._addresses) >= ADDRESS_LISTS:
                del self._addresses[next(iter(self._addresses))]
            hit = self._addresses[key] = (list(arrays), pointers(arrays))
        return hit[1]

    def padded(self, k: int) -> int:
        return -(-k // self.lanes) * self.lanes

    def __call__(
        self,
        inputs: list[np.ndarray],
        threads: int = 1,
        out: list[np.ndarray] | None = None,
    ) -> list[np.ndarray]:
        sig = self.signature
        k = check_inputs(sig, inputs, self.dtype)
        if k % self.lanes:
            raise ValueError(f"K = {k} must be a multiple of {self.lanes} lanes (pad it)")
        if out is None:
            out = [np.empty((nnz, k), self.np_dtype) for nnz in sig.nnz_out]
        if self._call(self._pointers(inputs), self._pointers(out), k, int(threads)):
            raise RuntimeError(f"{sig.name} failed in its batched evaluation")
        return out


@cache
def _build_cpu(source: str, sig: Signature, dtype: str, lanes: int) -> ctypes.CDLL:
    cxx = find_compiler(CXX_COMPILERS)
    if cxx is None:
        raise RuntimeError("the batched CPU backend needs a C++ compiler (g++ or clang++)")
    real = DTYPES[dtype][0]
    defines = [f"-DUVMS_REAL={real}", f"-DUVMS_LANES={lanes}", *_mvec_defines(dtype, lanes)]
    if dtype == "float32":
        # Subnormal floats take a microcode path ~100x slower than normal ones; float32
        # reaches them where float64 does not (the navigation function's high powers of
        # small distances: measured 16 ms instead of 0.1 ms per call at K = 256). The fast
        # mode flushes them to zero (FTZ/DAZ); float64 keeps IEEE behaviour, bit for bit
        # the single environment's.
        defines.append("-DUVMS_FLUSH_SUBNORMALS")
    header = (HERE / "lanes.hpp").read_text()
    head = '#include "lanes.hpp"\n#define casadi_real vreal\n'
    cut = cut_long_functions(source)
    flags = [*CXXFLAGS, *defines]
    key = hashlib.sha256(
        (head + cut + _cpu_driver(sig, lanes) + header + " ".join(flags) + cs.__version__).encode()
        + _cpu_identity()
    ).hexdigest()[:16]
    lib = cache_dir() / f"{sig.name}_batch_{dtype}x{lanes}_{key}.so"
    if not lib.exists():
        units = [head + u for u in translation_units(cut, default_units(cut))]
        units[0] += _cpu_driver(sig, lanes)
        libs = ("-lmvec", "-lm") if any("UVMS_SIN" in d for d in defines) else ("-lm",)
        build_library(
            f"{sig.name} ({dtype} x {lanes} lanes)",
            lib,
            cxx,
            [*flags, "-w"],
            units,
            ".cpp",
            libs,
            {"lanes.hpp": header},
        )
    return ctypes.CDLL(str(lib))


# The in-kernel error control's status per environment: accepted at once, accepted in
# parts, refused (the step's last output with ``Refinement``).
ACCEPTED, REFINED, REFUSED = 0, 1, 2


@dataclass(frozen=True)
class Refinement:
    """In-kernel error control for a period step laid out as the chain's (inputs ...,
    h last; outputs state, drift 12 x N, error 6 x N): ``uvms_env.sim.period``'s routine
    (``PeriodControl.accurate`` and the halving of ``PeriodControl.integrate``) written out
    in C with its constants (``kernel_list.period_refinement``), run by the thread of each
    environment that needs it, so that a few refined environments cost no extra launches.
    The kernel then writes one more output, (1, K): ``ACCEPTED``, ``REFINED`` or
    ``REFUSED``."""

    n_agents: int
    tol_pose: float
    tol_twist: float
    grasp_tol: float
    max_levels: int


def cuda_source(
    fn: cs.Function, real: str = "double", refine: Refinement | None = None
) -> tuple[str, Signature]:
    """CUDA C++ for ``fn``: the generated functions as device code, plus a kernel
    ``uvms_batch_kernel(const real* in[], real* out[], long k)`` with one thread per
    environment and the (nnz_i, K) layout, optionally with in-kernel error control
    (``Refinement``). Compiled by ``kernels_cuda`` (nvcc or NVRTC)."""
    sig = Signature.of(fn)
    full = generated_source(fn)
    top = _top_function(full, sig.name)
    src = full[: full.index(f"CASADI_SYMBOL_EXPORT int {sig.name}(")]  # host API from here
    lines, skipping = [], False
    device_function = re.compile(
        r"^(static )?(const )?(casadi_real|casadi_int|void|int)\s+\*?casadi_\w+\("
    )
    for line in src.split("\n"):
        if skipping:  # inside a host API function of several lines
            skipping = not line.startswith("}")
            continue
        if line.startswith("CASADI_SYMBOL_EXPORT"):
            skipping = not line.rstrip().endswith("}")
            continue
        if line.startswith("#include <math.h>"):
            continue  # NVRTC has the maths functions built in (INFINITY: below)
        if device_function.match(line) or re.match(r"^static const casadi_(int|real) ", line):
            line = "__device__ " + line
        lines.append(line)
    body = "\n".join(lines)
    # the generated code closes its extern "C" block at the end of the file
    n_in, n_out = len(sig.nnz_in), len(sig.nnz_out)
    control = "" if refine is None else _refinement_source(refine, sig, top)
    call = (
        f"{top}(arg, res, iw, w, 0);"
        if refine is None
        else "out[" + str(n_out) + "][e] = uvms_controlled_step(arg, res, iw, w);"
    )
    kernel = f"""
}} /* extern "C" */
{control}
extern "C" __global__ void uvms_batch_kernel(const casadi_real* const* in,
                                             casadi_real* const* out, long k) {{
  const long e = (long)blockIdx.x * blockDim.x + threadIdx.x;
  if (e >= k) return;
  casadi_real in_buf[{sum(sig.nnz_in) + 1}], out_buf[{sum(sig.nnz_out) + 1}];
  casadi_real w[{sig.sz_w + 1}];
  casadi_int iw[{sig.sz_iw + 1}];
  const casadi_real* arg[{max(sig.sz_arg, n_in)}];
  casadi_real* res[{max(sig.sz_res, n_out)}];
  const long nnz_in[{n_in}] = {{{", ".join(map(str, sig.nnz_in))}}};
  const long nnz_out[{n_out}] = {{{", ".join(map(str, sig.nnz_out))}}};
  casadi_real* p = in_buf;
  for (int i = 0; i < {n_in}; ++i) {{
    for (long j = 0; j < nnz_in[i]; ++j) p[j] = in[i][j * k + e];
    arg[i] = p;
    p += nnz_in[i];
  }}
  casadi_real* q = out_buf;
  for (int i = 0; i < {n_out}; ++i) {{ res[i] = q; q += nnz_out[i]; }}
  {call}
  q = out_buf;
  for (int i = 0; i < {n_out}; ++i) {{
    for (long j = 0; j < nnz_out[i]; ++j) out[i][j * k + e] = q[j];
    q += nnz_out[i];
  }}
}}
"""
    # NVRTC has <math.h>'s functions built in but not its INFINITY (casadi_inf): the bits of
    # +inf, as CUDA's math_constants.h spells it (the host build keeps its own definition)
    prelude = (
        f"#define casadi_real {real}\n#define casadi_int long long int\n"
        "#ifndef INFINITY\n#define INFINITY __int_as_float(0x7f800000)\n#endif\n"
    )
    return prelude + body + kernel, sig


def _refinement_source(r: Refinement, sig: Signature, top: str) -> str:
    """Device code of ``Refinement``: the accuracy test, then the halving of refused
    parts (``max_levels`` deep at most), in the thread of the environment."""
    nx, h_index = sig.nnz_in[0], len(sig.nnz_in) - 1
    if sig.nnz_out[:3] != (nx, 12 * r.n_agents, 6 * r.n_agents) or sig.nnz_in[-1] != 1:
        raise ValueError(f"{sig.name} is not laid out as a period step for Refinement")
    return f"""
/* PeriodControl.accurate: drift, grasp error and state within their bounds (NaN fails) */
__device__ static bool uvms_accurate(casadi_real* const* res) {{
  for (int j = 0; j < {12 * r.n_agents}; ++j) {{
    const casadi_real tol = (j % 12) < 6 ? {r.tol_pose!r} : {r.tol_twist!r};
    if (!(fabs(res[1][j]) <= tol)) return false;
  }}
  for (int j = 0; j < {6 * r.n_agents}; ++j)
    if (!(fabs(res[2][j]) <= {r.grasp_tol!r})) return false;
  for (int j = 0; j < {nx}; ++j)
    if (!isfinite(res[0][j])) return false;
  return true;
}}
__device__ static bool uvms_eval(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                                 casadi_real* w, const casadi_real* x0, casadi_real h) {{
  arg[0] = x0;
  arg[{h_index}] = &h;
  {top}(arg, res, iw, w, 0);
  return uvms_accurate(res);
}}
/* PeriodControl.integrate for one environment: the period from arg[0] over arg[{h_index}],
   a refused part halved (its halves in order), down to {r.max_levels} levels, where a part
   still refused refuses the period. The recursion unrolled into a stack of pending parts
   (recursion would need a stack depth the compiler cannot bound). The state lands in
   res[0]; returns {ACCEPTED} accepted at once, {REFINED} accepted in parts, {REFUSED} refused. */
__device__ static casadi_real uvms_controlled_step(const casadi_real** arg,
    casadi_real** res, casadi_int* iw, casadi_real* w) {{
  casadi_real x[{nx}];
  for (int j = 0; j < {nx}; ++j) x[j] = arg[0][j];
  const casadi_real period = arg[{h_index}][0];
  if (uvms_eval(arg, res, iw, w, x, period)) return {ACCEPTED};
  casadi_real part_h[{2 * r.max_levels + 2}];
  int part_level[{2 * r.max_levels + 2}];
  int top = 0;
  part_h[top] = period / 2; part_level[top++] = 1;  /* second half, done last */
  part_h[top] = period / 2; part_level[top++] = 1;  /* first half */
  while (top > 0) {{
    const casadi_real h = part_h[--top];
    const int level = part_level[top];
    if (uvms_eval(arg, res, iw, w, x, h)) {{
      for (int j = 0; j < {nx}; ++j) x[j] = res[0][j];
    }} else if (level >= {r.max_levels}) {{
      for (int j = 0; j < {nx}; ++j) res[0][j] = x[j];  /* where it stopped */
      return {REFUSED};
    }} else {{
      part_h[top] = h / 2; part_level[top++] = level + 1;
      part_h[top] = h / 2; part_level[top++] = level + 1;
    }}
  }}
  for (int j = 0; j < {nx}; ++j) res[0][j] = x[j];
  return {REFINED};
}}
"""


def _top_function(src: str, name: str) -> str:
    """The internal name (casadi_fN) that the host API function ``name`` calls."""
    found = re.search(
        rf"CASADI_SYMBOL_EXPORT int {name}\(.*?\{{\s*return (casadi_f\d+)\(", src, flags=re.S
    )
    if not found:
        raise RuntimeError(f"no generated function found for {name}")
    return found.group(1)
