"""The GPU target of ``kernels``: the generated function as a CUDA kernel, one thread per
environment, compiled at run time by NVRTC through CuPy (``pip install -e ".[gpu]"``).

Compiled once per machine and GPU architecture and cached on disk (nvcc's cubin under a
hash of the source, architecture and flags, or CuPy's own NVRTC cache); ``--arch`` builds
the cubins ahead of time and ``--report`` prints each kernel's registers and stack, both
without a GPU (docs/batched.md, "CUDA"). The kernel reads and writes device arrays in the
(nnz_i, K) layout of ``kernels``, so torch tensors on the same GPU pass through without a
copy (CUDA array interface / DLPack).

May import: numpy, casadi, cupy (imported here, so that nothing else needs it),
``uvms_env.vector.kernels``, ``kernels_emulated`` and, for ``--report``,
``kernels_check``.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import casadi as cs
import numpy as np

from uvms_env.dynamics.compiled import cache_dir
from uvms_env.vector.kernels import (
    BLOCK,
    DTYPES,
    NVRTC_OPTIONS,
    REGISTERS_PER_BLOCK,
    Refinement,
    Signature,
    check_inputs,
    check_outputs,
    cuda_source,
)
from uvms_env.vector.kernels_emulated import EmulatedCudaFunction

# The per-thread stack is left to the driver, not set here: "The driver automatically
# increases the per-thread stack size for each kernel launch as needed" (CUDA Driver API,
# cuCtxSetLimit, CU_LIMIT_STACK_SIZE), from the stack the loaded kernel declares
# (``local_size_bytes``). That figure is exact because every kernel's stack is static
# (no recursion: ``kernels_check`` fails otherwise). The fixed 32 KiB set before bounded
# nothing (the N = 6 float64 period step needs 54,640 bytes: docs/batched.md) and made the
# driver reserve 32 KiB for every thread the GPU can hold (~8.9 GB on an H100) where the
# kernels in use need less.
# -ftz=true: what CuPy passes NVRTC (below), so that a cubin built by nvcc computes as the
# one NVRTC builds (float32 subnormals flushed to zero, as the CPU backend's float32).
NVCC_FLAGS = ("-O3", "-std=c++17", "-ftz=true", "-diag-suppress", "177")


def cubin_path(source: str, sig: Signature, dtype: str, arch: str) -> Path:
    key = hashlib.sha256(
        (source + arch + " ".join(NVCC_FLAGS) + cs.__version__).encode()
    ).hexdigest()[:16]
    return cache_dir() / f"{sig.name}_cuda_{dtype}_sm{arch}_{key}.cubin"


def build_cubin(
    fn: cs.Function, dtype: str, arch: str, refine: Refinement | None = None
) -> Path | None:
    """The cached cubin of ``fn`` for ``arch`` (e.g. "90"), compiled with nvcc if it is
    not there yet; None when nvcc is not on PATH."""
    source, sig = cuda_source(fn, DTYPES[dtype][0], refine)
    path = cubin_path(source, sig, dtype, arch)
    if path.exists():
        return path
    nvcc = shutil.which("nvcc")
    if nvcc is None:
        return None
    src = path.with_suffix(f".{os.getpid()}.cu")
    part = path.with_suffix(f".{os.getpid()}.part")
    src.write_text(source)
    try:
        subprocess.run(
            [nvcc, *NVCC_FLAGS, f"-arch=sm_{arch}", "-cubin", "-o", str(part), str(src)],
            check=True,
        )
        part.replace(path)  # atomic, as for the CPU libraries
    finally:
        src.unlink(missing_ok=True)
    return path


def cupy_module():
    """CuPy, or an ImportError that says how to get it."""
    try:
        import cupy
    except ImportError as exc:  # pragma: no cover - depends on the machine
        raise ImportError(
            "the CUDA backend needs CuPy: pip install -e '.[gpu]' (and a CUDA GPU)"
        ) from exc
    return cupy


class CudaBatchedFunction:
    """``fn`` evaluated on K environments per launch, one GPU thread each.

    ``outputs = bf(inputs, out=None)``: ``inputs`` are (nnz_i, K) C-contiguous device
    arrays of the build's dtype (CuPy arrays, or anything CuPy takes without a copy,
    such as torch CUDA tensors); outputs are written to ``out`` or new CuPy arrays. With
    ``refine``, one more output (1, K) carries each environment's error-control status
    (``Refinement``)."""

    def __init__(
        self,
        fn: cs.Function,
        dtype: str = "float64",
        device: int = 0,
        block: int = BLOCK,
        refine: Refinement | None = None,
    ) -> None:
        self.block = int(block)
        if dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {dtype!r}")
        cp = cupy_module()
        self.cp = self.xp = cp
        self.dtype = dtype
        self.np_dtype = DTYPES[dtype][1]
        self.device = cp.cuda.Device(device)
        # the backend allocates its arrays on CuPy's current device: make it this kernel's,
        # or with device > 0 they would lie on GPU 0 and the kernel read them from another
        self.device.use()
        source, self.signature = cuda_source(fn, DTYPES[dtype][0], refine)
        self.nnz_out = self.signature.nnz_out + ((1,) if refine else ())
        with self.device:
            major, minor = self.device.compute_capability[:-1], self.device.compute_capability[-1]
            cubin = build_cubin(fn, dtype, major + minor, refine)
            if cubin is not None:
                module = cp.RawModule(path=str(cubin))
            else:
                module = cp.RawModule(code=source, options=NVRTC_OPTIONS)
            self._kernel = module.get_function("uvms_batch_kernel")
            # what the driver will reserve per thread (module docstring, BLOCK's comment)
            self.stack_bytes = int(self._kernel.local_size_bytes)
            self.registers = int(self._kernel.num_regs)
        if self.registers * self.block > REGISTERS_PER_BLOCK:
            raise ValueError(
                f"{self.signature.name}: {self.registers} registers x {self.block} threads "
                f"exceed a block's {REGISTERS_PER_BLOCK}; use a smaller block"
            )

    def padded(self, k: int) -> int:
        return k

    def __call__(self, inputs: list, out: list | None = None) -> list:
        cp, sig = self.cp, self.signature
        with self.device:
            arrays = [cp.asarray(a) for a in inputs]
            k = check_inputs(sig, arrays, self.dtype)
            if out is None:
                out = [cp.empty((nnz, k), self.np_dtype) for nnz in self.nnz_out]
            if any(isinstance(a, np.ndarray) for a in out):
                # cp.asarray would copy them to the device and the results stay there
                raise TypeError("outputs must be device arrays (CuPy, torch CUDA tensors)")
            outs = [cp.asarray(a) for a in out]
            check_outputs(self.nnz_out, outs, k, self.dtype)
            ins_ptr = cp.asarray(np.array([a.data.ptr for a in arrays], np.uint64))
            outs_ptr = cp.asarray(np.array([a.data.ptr for a in outs], np.uint64))
            grid = (k + self.block - 1) // self.block
            self._kernel((grid,), (self.block,), (ins_ptr, outs_ptr, np.int64(k)))
        return out


def cuda_function(
    fn: cs.Function,
    dtype: str,
    device: int | str,
    threads: int = 1,
    refine: Refinement | None = None,
) -> CudaBatchedFunction | EmulatedCudaFunction:
    """The CUDA kernel of ``fn`` on GPU ``device`` (an int), or with ``device="cpu"`` the
    same kernel source compiled for the host (``kernels_emulated``: the GPU backend
    tested without a GPU; ``threads`` OpenMP threads)."""
    if device == "cpu":
        return EmulatedCudaFunction(fn, dtype, refine, threads)
    if isinstance(device, bool) or not isinstance(device, int | np.integer):
        raise ValueError(f"device must be a GPU index (int) or 'cpu', got {device!r}")
    return CudaBatchedFunction(fn, dtype, int(device), refine=refine)


def main(argv: list[str] | None = None) -> None:
    """Build the period step's cubins ahead of time (nvcc, no GPU needed), or with
    --report compile every kernel the backend launches with NVRTC and ptxas and print what
    each needs per thread (``kernels_check``; the cuda-check extra, no GPU needed)."""
    from uvms_env.scenarios import make
    from uvms_env.sim.simulator import symbolic_chain

    ap = argparse.ArgumentParser(
        prog="python -m uvms_env.vector.kernels_cuda", description=main.__doc__, allow_abbrev=False
    )
    ap.add_argument("--arch", nargs="+", default=["90"], help="compute capabilities, e.g. 80 89 90")
    ap.add_argument("--n-agents", type=int, nargs="+", default=[2])
    ap.add_argument("--dtype", nargs="+", default=["float64", "float32"])
    ap.add_argument("--report", action="store_true", help="the NVRTC + ptxas check")
    ap.add_argument("--jobs", type=int, default=1, help="--report: compiles in parallel")
    args = ap.parse_args(argv)
    if args.report:
        from uvms_env.vector.kernels_check import check

        try:
            check(args.arch, args.n_agents, args.dtype, args.jobs, echo=_flushed)
        except RuntimeError as exc:
            raise SystemExit(str(exc)) from None
        return
    from uvms_env.vector.kernel_list import period_refinement

    for n in args.n_agents:
        s = make("paper") if n == 2 else make("random", n_agents=n, seed=0)
        chain = symbolic_chain(n, s.object_shape, s.object_size, s.period, s.substeps)
        for dtype in args.dtype:
            for arch in args.arch:
                path = build_cubin(chain.step, dtype, arch, period_refinement(n, dtype))
                print(path if path else "nvcc not found: the kernel will be compiled by NVRTC")


def _flushed(line: str) -> None:
    print(line, flush=True)  # a CI log shows each kernel as it is done


if __name__ == "__main__":
    main()
