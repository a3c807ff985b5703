"""The CUDA backend's compile path without a GPU: NVIDIA's NVRTC and ptxas (the
``cuda-check`` wheels) compile the backend's small kernels for an H100 with the options
CuPy passes, refuse what the host emulation accepts, and the backend itself hands NVRTC
(through a CuPy stand-in) exactly that source and those options, takes the stack and
registers from the loaded kernel and sets no stack limit of its own. The full check of
every kernel (minutes each) is ``.ci/run``'s last step, not a test."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import casadi as cs
import pytest

from uvms_env.vector import kernel_list, kernels_cuda
from uvms_env.vector.kernels import BLOCK, NVRTC_OPTIONS, REGISTERS_PER_BLOCK, cuda_source
from uvms_env.vector.kernels_check import (
    CUPY_ADDED_OPTIONS,
    CompileError,
    Report,
    assemble,
    backend_kernels,
    compile_ptx,
    compile_report,
    nvidia_tools,
    nvrtc_options,
    parse_ptxas,
)

TOOLS = nvidia_tools()
needs_wheels = pytest.mark.skipif(
    TOOLS is None,
    reason="NVIDIA's NVRTC and ptxas wheels absent (pip install -e '.[cuda-check]')",
)
SMALL = ("prior_features",)  # under a second; the others take seconds to minutes


def _kernel(role: str):
    return next(k for k in backend_kernels(2) if k.role == role)


def test_the_check_lists_every_kernel_the_backend_compiles():
    roles = [k.role for k in backend_kernels(2)]
    assert roles == [
        "period step",
        "kinematics",
        "prior_steady",
        "prior_features",
        "kinematics (noiseless)",
    ]
    step = backend_kernels(2)[0]
    assert step.refine == kernel_list.period_refinement(2)
    # with noise and the internal wrench inside, and with neither: both variants compile
    assert backend_kernels(2)[1].fn.name().endswith("_noisy_chain_internal_wrench_n2")
    assert not backend_kernels(2)[-1].fn.name().endswith(("_noisy", "_wrench_n2"))


@needs_wheels
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_small_kernels_compile_for_an_h100_within_a_block_and_a_static_stack(dtype):
    for role in SMALL:
        report = compile_report(_kernel(role), 2, dtype, "90", TOOLS)
        assert 0 < report.registers <= 255, report.line()  # the architecture's maximum
        assert report.registers * report.block <= REGISTERS_PER_BLOCK
        assert report.block == BLOCK
        assert report.static_stack and report.stack >= 0
        assert report.local_memory == report.stack * 132 * 2048
        assert not report.problems()


@needs_wheels
def test_nvrtc_refuses_a_host_function_called_from_the_kernel_the_host_build_accepts():
    """What the emulated backend cannot see: a generated function left without
    ``__device__`` compiles for the host, and NVRTC refuses the kernel that calls it."""
    source, _ = cuda_source(_kernel("prior_features").fn, "double")
    ptx = compile_ptx(TOOLS[0], source, nvrtc_options("90"))
    assert ".entry uvms_batch_kernel" in ptx
    marked = [line for line in source.split("\n") if line.startswith("__device__ static int")]
    assert marked
    broken = source.replace(marked[-1], marked[-1].removeprefix("__device__ "))
    with pytest.raises(CompileError, match="host functions are not allowed"):
        compile_ptx(TOOLS[0], broken, nvrtc_options("90"))


def test_ptxas_reports_are_parsed_for_the_entry_with_every_functions_spills():
    text = """ptxas info    : 320 bytes gmem
ptxas info    : Compiling entry function 'uvms_batch_kernel' for 'sm_90'
ptxas info    : Function properties for uvms_batch_kernel
    3176 bytes stack frame, 5096 bytes spill stores, 6400 bytes spill loads
ptxas info    : Used 255 registers, used 0 barriers, 3176 bytes cumulative stack size
ptxas info    : Function properties for casadi_f1
    64 bytes stack frame, 8 bytes spill stores, 16 bytes spill loads
"""
    assert parse_ptxas(text) == (255, 3176, 5104, 6416, True)
    recursive = text + "ptxas warning : Stack size for entry function 'uvms_batch_kernel' "
    recursive += "cannot be statically determined\n"
    assert parse_ptxas(recursive)[4] is False
    with pytest.raises(CompileError, match="no register count"):
        parse_ptxas("ptxas info    : 0 bytes gmem\n")


def test_the_cubin_cache_key_changes_with_source_dtype_arch_and_flags(monkeypatch):
    x = cs.SX.sym("x", 2)
    fn = cs.Function("uvms_twice", [x], [2 * x])
    source, sig = cuda_source(fn, "double")
    path = kernels_cuda.cubin_path(source, sig, "float64", "90")
    assert path == kernels_cuda.cubin_path(source, sig, "float64", "90")
    others = {
        kernels_cuda.cubin_path(source + "\n", sig, "float64", "90"),
        kernels_cuda.cubin_path(source, sig, "float32", "90"),
        kernels_cuda.cubin_path(source, sig, "float64", "80"),
    }
    monkeypatch.setattr(kernels_cuda, "NVCC_FLAGS", (*kernels_cuda.NVCC_FLAGS, "-G"))
    others.add(kernels_cuda.cubin_path(source, sig, "float64", "90"))
    assert len(others | {path}) == 5
    assert path.name.startswith("uvms_twice_cuda_float64_sm90_") and path.suffix == ".cubin"


class _Device:
    compute_capability = "90"

    def __init__(self, index: int) -> None:
        self.index = index

    def use(self) -> None:
        pass

    def __enter__(self) -> _Device:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def _cupy_stand_in(calls: list) -> types.ModuleType:
    """CuPy's module-loading surface: RawModule compiles its code with the real NVRTC and
    ptxas (the options CuPy adds included, ``nvrtc_options``) and its kernel carries the
    ptxas figures as CuPy's RawKernel attributes do. Everything else a test would reach
    (a stack limit, the runtime) is absent, so that using it fails."""

    class RawModule:
        def __init__(self, *, code: str | None = None, path: str | None = None, options=()):
            calls.append({"code": code, "path": path, "options": options})
            assert TOOLS is not None and code is not None
            ptx = compile_ptx(TOOLS[0], code, (*options, *CUPY_ADDED_OPTIONS, "-arch=compute_90"))
            self._report = parse_ptxas(assemble(TOOLS[1], ptx, "90"))

        def get_function(self, name: str) -> types.SimpleNamespace:
            assert name == "uvms_batch_kernel"
            registers, stack, *_ = self._report
            return types.SimpleNamespace(num_regs=registers, local_size_bytes=stack)

    cuda = types.SimpleNamespace(Device=_Device)
    return types.SimpleNamespace(cuda=cuda, RawModule=RawModule)  # type: ignore[return-value]


@needs_wheels
def test_the_backend_hands_nvrtc_the_checked_source_and_options_and_sets_no_stack(
    monkeypatch, tmp_path: Path
):
    calls: list = []
    monkeypatch.setitem(sys.modules, "cupy", _cupy_stand_in(calls))
    monkeypatch.setattr(kernels_cuda.shutil, "which", lambda name: None)  # no nvcc: NVRTC
    monkeypatch.setenv("UVMS_ENV_CACHE", str(tmp_path))
    kernel = _kernel("prior_features")
    bf = kernels_cuda.cuda_function(kernel.fn, "float32", 0)
    assert len(calls) == 1 and calls[0]["path"] is None
    assert calls[0]["code"] == cuda_source(kernel.fn, "float", None)[0]
    assert calls[0]["options"] == NVRTC_OPTIONS
    assert nvrtc_options("90")[: len(NVRTC_OPTIONS)] == NVRTC_OPTIONS
    report = compile_report(kernel, 2, "float32", "90", TOOLS)
    assert (bf.registers, bf.stack_bytes) == (report.registers, report.stack)
    assert bf.block == BLOCK and bf.nnz_out == bf.signature.nnz_out
    assert not hasattr(kernels_cuda, "STACK_BYTES")
    assert not list(tmp_path.glob("*.cubin"))  # nothing cached without nvcc


def test_the_backend_refuses_a_block_its_kernel_has_not_the_registers_for(monkeypatch):
    class RawModule:
        def __init__(self, **kwargs: object) -> None:
            pass

        def get_function(self, name: str) -> types.SimpleNamespace:
            return types.SimpleNamespace(num_regs=255, local_size_bytes=0)

    cuda = types.SimpleNamespace(Device=_Device)
    stand_in = types.SimpleNamespace(cuda=cuda, RawModule=RawModule)
    monkeypatch.setitem(sys.modules, "cupy", stand_in)
    monkeypatch.setattr(kernels_cuda.shutil, "which", lambda name: None)
    x = cs.SX.sym("x", 2)
    fn = cs.Function("uvms_twice", [x], [2 * x])
    assert kernels_cuda.CudaBatchedFunction(fn, block=256).registers == 255
    with pytest.raises(ValueError, match="255 registers x 512 threads exceed"):
        kernels_cuda.CudaBatchedFunction(fn, block=512)


def test_a_cached_cubin_is_loaded_without_compiling(monkeypatch, tmp_path: Path):
    """The nvcc cache: a cubin under the key of this source, dtype, architecture and flags
    is loaded as it is (nvcc and NVRTC untouched); another architecture's is not."""
    loaded: list = []

    class RawModule:
        def __init__(self, *, code: str | None = None, path: str | None = None, options=()):
            loaded.append((code is not None, path))

        def get_function(self, name: str) -> types.SimpleNamespace:
            return types.SimpleNamespace(num_regs=32, local_size_bytes=0)

    cuda = types.SimpleNamespace(Device=_Device)
    monkeypatch.setitem(sys.modules, "cupy", types.SimpleNamespace(cuda=cuda, RawModule=RawModule))
    monkeypatch.setattr(kernels_cuda.shutil, "which", lambda name: None)
    monkeypatch.setenv("UVMS_ENV_CACHE", str(tmp_path))
    x = cs.SX.sym("x", 2)
    fn = cs.Function("uvms_twice", [x], [2 * x])
    source, sig = cuda_source(fn, "double")
    kernels_cuda.cubin_path(source, sig, "float64", "80").write_bytes(b"sm_80")
    kernels_cuda.CudaBatchedFunction(fn)  # the stand-in device is sm_90: NVRTC
    cubin = kernels_cuda.cubin_path(source, sig, "float64", "90")
    cubin.write_bytes(b"sm_90")
    kernels_cuda.CudaBatchedFunction(fn)
    assert loaded == [(True, None), (False, str(cubin))]
    assert "-ftz=true" in kernels_cuda.NVCC_FLAGS  # nvcc's cubins compute as NVRTC's


@needs_wheels
@pytest.mark.parametrize(
    ("dtype", "bits"), [("float64", "0d7FF0000000000000"), ("float32", "0f7F800000")]
)
def test_infinity_in_a_generated_function_compiles_with_nvrtc_as_plus_infinity(dtype, bits):
    """CasADi spells inf as <math.h>'s INFINITY, which the host has and NVRTC has not (the
    kinematics kernel's first NVRTC compile failed on it)."""
    x = cs.SX.sym("x", 2)
    fn = cs.Function("uvms_inf", [x], [cs.if_else(x[0] > 0, cs.inf, x[1])])
    source, _ = cuda_source(fn, "double" if dtype == "float64" else "float")
    assert "casadi_inf" in source
    ptx = compile_ptx(TOOLS[0], source, nvrtc_options("90"))
    assert bits in ptx


def test_a_report_names_the_gpu_it_assumes_and_none_for_other_architectures():
    def report(arch: str) -> Report:
        return Report("navigation", 2, "float64", arch, 162, 536, 0, 0, True, BLOCK, 0.1, 0.2)

    assert report("90").local_memory == 536 * 132 * 2048
    assert report("80").local_memory == 536 * 108 * 2048
    assert "(H100 SXM)" in report("90").line() and "(A100)" in report("80").line()
    assert report("89").local_memory is None and "unknown" in report("89").line()
