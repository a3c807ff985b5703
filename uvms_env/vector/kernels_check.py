"""The CUDA backend's kernels compiled for a GPU architecture on a machine without a GPU:
NVIDIA's run-time compiler (NVRTC, ``libnvrtc.so.12``) and assembler (``ptxas``), from
the PyPI wheels ``nvidia-cuda-nvrtc-cu12`` and ``nvidia-cuda-nvcc-cu12`` (``pip install
-e ".[cuda-check]"``), run on the CPU.

Every kernel the backend launches (``backend_kernels``) is compiled by NVRTC with CuPy's
options (``nvrtc_options``) and assembled by ``ptxas -v``; ``check`` fails on a compile
error, an unbounded stack or registers beyond a block's register file. Why, the command
and the measured table: docs/batched.md, "CUDA kernels: compile check".

May import: numpy, casadi, ``uvms_env`` below ``vector`` (the functions the backend
batches, as ``engine`` and ``batched_simulator`` make them) and the sibling ``vector`` modules.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.util
import re
import subprocess
import tempfile
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import casadi as cs

from uvms_env.vector.kernels import (
    BLOCK,
    DTYPES,
    NVRTC_OPTIONS,
    REGISTERS_PER_BLOCK,
    Refinement,
    cuda_source,
)

# The GPUs assumed per architecture for the local memory at full occupancy: the driver
# reserves the kernel's stack for every thread the GPU can hold at once (SMs x resident
# threads per SM), whatever the launch.
GPUS = {"90": ("H100 SXM", 132, 2048), "80": ("A100", 108, 2048)}
# What CuPy appends to the caller's options when it compiles a RawModule with NVRTC
# (cupy.cuda.compiler: flush single-precision subnormals to zero); the architecture comes
# last. Its include directories (-I) are left out: the kernels include nothing.
CUPY_ADDED_OPTIONS = ("-ftz=true",)


class CompileError(RuntimeError):
    """NVRTC or ptxas refused a kernel; the message carries the compiler's log."""


@dataclass(frozen=True)
class Kernel:
    """One kernel the CUDA backend compiles: its role, the CasADi function and the error
    control the period step carries."""

    role: str
    fn: cs.Function
    refine: Refinement | None = None


@dataclass(frozen=True)
class Report:
    """What ptxas says of one kernel for one architecture, and how the backend launches
    it."""

    kernel: str
    n_agents: int
    dtype: str
    arch: str
    registers: int
    stack: int  # bytes per thread (the entry's cumulative stack)
    spill_stores: int  # bytes, over the kernel and the device functions it calls
    spill_loads: int
    static_stack: bool
    block: int
    nvrtc_s: float
    ptxas_s: float

    @property
    def local_memory(self) -> int | None:
        """Bytes the driver reserves for the stack at full occupancy on ``GPUS[arch]``;
        None for an architecture no GPU is assumed for."""
        if self.arch not in GPUS:
            return None
        _, sms, threads = GPUS[self.arch]
        return self.stack * sms * threads

    def problems(self) -> list[str]:
        found = []
        if self.registers * self.block > REGISTERS_PER_BLOCK:
            found.append(
                f"{self.registers} registers x {self.block} threads exceed a block's "
                f"{REGISTERS_PER_BLOCK}"
            )
        if not self.static_stack:
            found.append("its stack size cannot be statically determined")
        return found

    def line(self) -> str:
        local = self.local_memory
        occupancy = (
            f"{local / 1e9:.2f} GB ({GPUS[self.arch][0]})"
            if local is not None
            else f"unknown (no GPU assumed for sm_{self.arch}: GPUS)"
        )
        return (
            f"{self.kernel} N={self.n_agents} {self.dtype} sm_{self.arch}: registers "
            f"{self.registers}, stack {self.stack}, spills {self.spill_stores}/"
            f"{self.spill_loads} (stores/loads, bytes), block {self.block}, local memory at "
            f"full occupancy {occupancy}; NVRTC {self.nvrtc_s:.0f} s, ptxas {self.ptxas_s:.0f} s"
        )


# -- the NVIDIA wheels -------------------------------------------------------------------
def nvidia_tools() -> tuple[Path, Path] | None:
    """(libnvrtc.so.12, ptxas) from the installed wheels, or None without them."""
    spec = importlib.util.find_spec("nvidia")
    if spec is None or not spec.submodule_search_locations:
        return None
    for root in map(Path, spec.submodule_search_locations):
        lib = root / "cuda_nvrtc" / "lib" / "libnvrtc.so.12"
        ptxas = root / "cuda_nvcc" / "bin" / "ptxas"
        if lib.exists() and ptxas.exists():
            return lib, ptxas
    return None


@cache
def _nvrtc(path: str) -> ctypes.CDLL:
    lib = ctypes.CDLL(path)
    p = ctypes.c_void_p
    lib.nvrtcCreateProgram.argtypes = [
        ctypes.POINTER(p),
        ctypes.c_char_p,
        ctypes.c_char_p,
        ctypes.c_int,
        p,
        p,
    ]
    lib.nvrtcCompileProgram.argtypes = [p, ctypes.c_int, ctypes.POINTER(ctypes.c_char_p)]
    for name in ("nvrtcGetProgramLogSize", "nvrtcGetPTXSize"):
        getattr(lib, name).argtypes = [p, ctypes.POINTER(ctypes.c_size_t)]
    for name in ("nvrtcGetProgramLog", "nvrtcGetPTX"):
        getattr(lib, name).argtypes = [p, ctypes.c_char_p]
    lib.nvrtcDestroyProgram.argtypes = [ctypes.POINTER(p)]
    lib.nvrtcGetErrorString.restype = ctypes.c_char_p
    return lib


def nvrtc_options(arch: str) -> tuple[str, ...]:
    """NVRTC's options as CuPy passes them for the backend's RawModule, PTX for ``arch``
    (CuPy asks NVRTC for a cubin where it can, which runs the same ptxas inside)."""
    return (*NVRTC_OPTIONS, *CUPY_ADDED_OPTIONS, f"-arch=compute_{arch}")


def compile_ptx(lib_path: Path, source: str, options: Iterable[str]) -> str:
    """PTX of ``source`` by NVRTC; CompileError with NVRTC's log if it refuses it."""
    lib = _nvrtc(str(lib_path))
    prog = ctypes.c_void_p()
    check = _nvrtc_check(lib)
    check(lib.nvrtcCreateProgram(ctypes.byref(prog), source.encode(), b"kernel.cu", 0, None, None))
    try:
        opts = [o.encode() for o in options]
        status = lib.nvrtcCompileProgram(prog, len(opts), (ctypes.c_char_p * len(opts))(*opts))
        size = ctypes.c_size_t()
        check(lib.nvrtcGetProgramLogSize(prog, ctypes.byref(size)))
        log = ctypes.create_string_buffer(size.value)
        check(lib.nvrtcGetProgramLog(prog, log))
        if status:
            raise CompileError(f"NVRTC: {_nvrtc_error(lib, status)}\n{log.value.decode()}")
        check(lib.nvrtcGetPTXSize(prog, ctypes.byref(size)))
        ptx = ctypes.create_string_buffer(size.value)
        check(lib.nvrtcGetPTX(prog, ptx))
        return ptx.value.decode()
    finally:
        lib.nvrtcDestroyProgram(ctypes.byref(prog))


def _nvrtc_error(lib: ctypes.CDLL, status: int) -> str:
    return lib.nvrtcGetErrorString(status).decode()


def _nvrtc_check(lib: ctypes.CDLL) -> Callable[[int], None]:
    def check(status: int) -> None:
        if status:
            raise CompileError(f"NVRTC: {_nvrtc_error(lib, status)}")

    return check


def assemble(ptxas: Path, ptx: str, arch: str) -> str:
    """ptxas's verbose report of ``ptx`` for sm_``arch`` (-O3, as the driver and NVRTC
    assemble it); CompileError with its output if it fails."""
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "kernel.ptx"
        src.write_text(ptx)
        done = subprocess.run(
            [str(ptxas), f"-arch=sm_{arch}", "-O3", "-v", str(src), "-o", str(src) + ".cubin"],
            capture_output=True,
            text=True,
        )
    if done.returncode:
        raise CompileError(f"ptxas: {done.stdout}{done.stderr}")
    return done.stdout + done.stderr


ENTRY = "uvms_batch_kernel"


def parse_ptxas(text: str, entry: str = ENTRY) -> tuple[int, int, int, int, bool]:
    """(registers, stack bytes, spill store bytes, spill load bytes, static stack) of the
    entry ``entry`` in ptxas -v output. Spills are summed over every function listed (the
    device functions the kernel calls spill into its stack too)."""
    registers = stack = None
    spill_stores = spill_loads = 0
    frames: dict[str, int] = {}
    current = None
    for line in text.splitlines():
        found = re.search(r"Function properties for (\S+)", line)
        if found:
            current = found.group(1)
            continue
        found = re.search(
            r"(\d+) bytes stack frame, (\d+) bytes spill stores, (\d+) bytes spill loads", line
        )
        if found and current is not None:
            frames[current] = int(found.group(1))
            spill_stores += int(found.group(2))
            spill_loads += int(found.group(3))
            continue
        found = re.search(rf"Compiling entry function '{entry}'", line)
        if found:
            current = entry
            continue
        found = re.search(r"Used (\d+) registers", line)
        if found and current == entry:
            registers = int(found.group(1))
            cumulative = re.search(r"(\d+) bytes cumulative stack size", line)
            if cumulative:
                stack = int(cumulative.group(1))
    if registers is None:
        raise CompileError(f"no register count for {entry} in ptxas's output:\n{text}")
    if stack is None:  # older ptxas: the entry's own frame
        stack = frames.get(entry, 0)
    static = "cannot be statically determined" not in text
    return registers, stack, spill_stores, spill_loads, static


# -- the kernels the backend launches ----------------------------------------------------
@cache
def backend_kernels(n_agents: int) -> tuple[Kernel, ...]:
    """Every kernel ``VectorEnv(backend="cuda")`` may compile for ``n_agents`` robots, as
    ``BatchedSimulator`` and ``BatchedEngine`` make them: the period step with the error
    control of ``period_refinement``, then ``kernel_list.kernel_functions`` with every
    option that adds one on (sensor noise, the internal wrench inside the kinematics, the
    priors) and the noiseless kinematics without the wrench. The scenario is the one
    ``kernels_cuda``'s cubin builder uses ("paper" for N = 2, else "random")."""
    from uvms_env.dynamics import ObjectModel
    from uvms_env.scenarios import make
    from uvms_env.sim.simulator import symbolic_chain
    from uvms_env.vector.kernel_list import kernel_functions, period_refinement

    s = make("paper") if n_agents == 2 else make("random", n_agents=n_agents, seed=0)
    chain = symbolic_chain(n_agents, s.object_shape, s.object_size, s.period, s.substeps)
    n_seg = len(ObjectModel(s.object_shape, s.object_size).segments)
    kernels = [Kernel("period step", chain.step, period_refinement(n_agents))]
    for noisy in (True, False):
        key = s.object_key if noisy else None
        fns = kernel_functions(n_agents, n_seg, noisy, chain, wrench=noisy, prior_object_key=key)
        for role, fn in fns.items():
            name = f"{role} (noiseless)" if role == "kinematics" and not noisy else role
            if noisy or role == "kinematics":
                kernels.append(Kernel(name, fn))
    return tuple(kernels)


def refinement(kernel: Kernel, n_agents: int, dtype: str) -> Refinement | None:
    """The error control ``kernel`` carries in ``dtype`` (its tolerances are the
    precision's, as the backend builds it)."""
    if kernel.refine is None:
        return None
    from uvms_env.vector.kernel_list import period_refinement

    return period_refinement(n_agents, dtype)


def compile_report(
    kernel: Kernel, n_agents: int, dtype: str, arch: str, tools: tuple[Path, Path]
) -> Report:
    """NVRTC then ptxas on ``kernel``'s backend source for ``arch`` (e.g. "90")."""
    import time

    source, _ = cuda_source(kernel.fn, DTYPES[dtype][0], refinement(kernel, n_agents, dtype))
    lib, ptxas = tools
    t0 = time.perf_counter()
    ptx = compile_ptx(lib, source, nvrtc_options(arch))
    t1 = time.perf_counter()
    text = assemble(ptxas, ptx, arch)
    t2 = time.perf_counter()
    registers, stack, stores, loads, static = parse_ptxas(text)
    return Report(
        kernel.role,
        n_agents,
        dtype,
        arch,
        registers,
        stack,
        stores,
        loads,
        static,
        BLOCK,
        t1 - t0,
        t2 - t1,
    )


def _job(args: tuple[int, str, int, str, str]) -> Report:
    n_agents, role, index, dtype, arch = args
    tools = nvidia_tools()
    assert tools is not None
    kernel = backend_kernels(n_agents)[index]
    assert kernel.role == role
    return compile_report(kernel, n_agents, dtype, arch, tools)


def check(
    archs: Iterable[str],
    n_agents: Iterable[int],
    dtypes: Iterable[str],
    jobs: int = 1,
    echo: Callable[[str], None] = print,
) -> list[Report]:
    """Compile every backend kernel for each architecture, N and dtype (kernels that do
    not depend on N once, at the first N); ``echo`` each report's line as it comes.
    RuntimeError at the end naming every kernel that failed or breaks a limit."""
    tools = nvidia_tools()
    if tools is None:
        raise RuntimeError(
            "the compile check needs NVIDIA's NVRTC and ptxas wheels: "
            "pip install -e '.[cuda-check]'"
        )
    work, seen = [], set()
    for n in n_agents:
        for index, kernel in enumerate(backend_kernels(n)):
            for dtype in dtypes:
                refine = refinement(kernel, n, dtype)
                key = hashlib.sha256(
                    cuda_source(kernel.fn, DTYPES[dtype][0], refine)[0].encode()
                ).hexdigest()
                for arch in archs:
                    if (key, arch) not in seen:  # the same source compiles the same
                        seen.add((key, arch))
                        work.append((n, kernel.role, index, dtype, str(arch)))
    # the heaviest first (the period step, large N), so that the pool ends together
    work.sort(key=lambda w: (w[1] != "period step", -w[0]))
    reports, failures = [], []
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = [(w, pool.submit(_job, w)) for w in work]
        for w, future in futures:
            n, role, _, dtype, arch = w
            try:
                report = future.result()
            except CompileError as exc:
                failures.append(f"{role} N={n} {dtype} sm_{arch}: {exc}")
                echo(f"{role} N={n} {dtype} sm_{arch}: FAILED to compile")
                continue
            reports.append(report)
            echo(report.line())
            failures += [f"{report.kernel} N={n} {dtype} sm_{arch}: {p}" for p in report.problems()]
    if failures:
        raise RuntimeError("CUDA kernel check failed:\n" + "\n".join(failures))
    return reports


__all__ = [
    "GPUS",
    "CompileError",
    "Kernel",
    "Report",
    "backend_kernels",
    "check",
    "compile_ptx",
    "compile_report",
    "nvidia_tools",
    "nvrtc_options",
    "parse_ptxas",
]
