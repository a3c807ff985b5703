"""Compile CasADi functions to shared libraries once, cache them on disk, load them fast.

A CasADi function generated as C and compiled is much faster than CasADi's virtual
machine; compiling costs seconds, so the library is cached under a key that hashes the
generated source, the compiler flags and the CasADi version (once per machine). The source
is cut and compiled in parallel units (``split_source``); each compile says on a line of
its own how long it should take, and its time is logged in the cache folder.

Cache folder: ``$UVMS_ENV_CACHE`` or the user cache dir (``platformdirs``). Set
``UVMS_ENV_NO_COMPILE=1`` to skip compilation and use the virtual machine instead
(slower, same results), e.g. where no C compiler is installed.

May import: numpy, casadi, platformdirs, tqdm (the announcement above a running bar) and
``uvms_env.dynamics.split_source``.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import hashlib
import importlib
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import casadi as cs
import numpy as np
import platformdirs

from uvms_env.dynamics.split_source import (
    compile_units,
    cut_long_functions,
    default_units,
    translation_units,
)

# Native code is tied to the CPU, so the CPU's identity is part of the cache key.
CFLAGS = ("-O3", "-march=native", "-fPIC", "-shared")


@functools.cache
def _cpu_identity() -> bytes:
    ident = platform.machine() + platform.processor()
    try:
        with open("/proc/cpuinfo") as fh:
            wanted = {line for line in fh if line.startswith(("model name", "flags"))}
        ident += "".join(sorted(wanted))
    except OSError:
        pass
    return ident.encode()


def machine_description() -> str:
    """The CPU the libraries are compiled for, as benchmarks report it: its model name,
    whether it has AVX-512 (avx512f) and AVX2, and the cores this process may use."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name":
                    model = value.strip()
                elif key.strip() == "flags":
                    flags = set(value.split())
                if flags and model:
                    break
    except OSError:
        pass
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    yes = {True: "yes", False: "no"}
    return (
        f"{model} (avx512f: {yes['avx512f' in flags]}, avx2: {yes['avx2' in flags]}), {cores} cores"
    )


def cache_dir() -> Path:
    root = os.environ.get("UVMS_ENV_CACHE") or platformdirs.user_cache_dir("uvms_env")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path


C_COMPILERS = ("CC", "gcc", "cc", "clang")
CXX_COMPILERS = ("CXX", "g++", "c++", "clang++")


def find_compiler(candidates: tuple[str, ...] = C_COMPILERS) -> str | None:
    """The first of ``candidates`` on PATH: the first entry names an environment variable
    the user may set (CC, CXX), the others are program names."""
    env, *names = candidates
    for cc in (os.environ.get(env), *names):
        if cc and shutil.which(cc):
            return cc
    return None


def generated_source(fn: cs.Function) -> str:
    """CasADi's C for ``fn`` and everything it calls."""
    with tempfile.TemporaryDirectory() as tmp:
        cg = cs.CodeGenerator(f"{fn.name()}.c", {"with_header": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        return (Path(tmp) / f"{fn.name()}.c").read_text()


def compile_function(fn: cs.Function) -> cs.Function:
    """A compiled, cached equivalent of ``fn`` (same name, inputs and outputs)."""
    if compiler_off():
        return fn
    return cs.external(fn.name(), str(compiled_library(fn.name(), generated_source(fn))))


def compiler_off() -> bool:
    """No compilation here: ``UVMS_ENV_NO_COMPILE`` is set or there is no C compiler."""
    return bool(os.environ.get("UVMS_ENV_NO_COMPILE")) or find_compiler() is None


def compiled_library(name: str, source: str) -> Path:
    """The shared library of the C ``source`` (CasADi's generated C, and what a caller
    appends to it in CasADi's calling convention), compiled once and cached under a key of
    the source, the flags, the CasADi version and the CPU; ``name`` names the file. Call
    only where ``compiler_off()`` is false."""
    cc = find_compiler()
    assert cc is not None
    code = cut_long_functions(source)
    key = hashlib.sha256(
        code.encode() + " ".join(CFLAGS).encode() + cs.__version__.encode() + _cpu_identity()
    )
    lib = cache_dir() / f"{name}_{key.hexdigest()[:16]}.so"
    if not lib.exists():
        units = translation_units(code, default_units(code))
        build_library(name, lib, cc, CFLAGS, units, ".c")
    return lib


# Seconds per generated line and translation unit, compiled at -O3 on one core, where this
# machine has no record yet (measured on the 2-core AVX-512 machine, 2026-12-01: the chain
# step 8.4-9.2 s for 50,000-52,000 lines in 2 units, the controller's library 14.5-22 s for
# 115,000-130,000: 2.2e-4 to 3.7e-4; the first announcement is within 2x of either, the
# log's own rate takes over after it). A 3x slower machine is 3x off until its first record.
SECONDS_PER_LINE = 2.6e-4
_LOG = "compile_log.jsonl"


def expected_seconds(lines: int, units: int) -> float:
    """How long a library of ``lines`` generated lines in ``units`` parallel units should
    take to compile here: the rate of this machine's last compiles (``compile_log.jsonl``
    in the cache), else ``SECONDS_PER_LINE``."""
    try:
        rows = [json.loads(r) for r in (cache_dir() / _LOG).read_text().splitlines()[-50:]]
        rate = sum(r["seconds"] * r["units"] for r in rows) / sum(r["lines"] for r in rows)
    except (OSError, ValueError, KeyError, ZeroDivisionError):
        rate = SECONDS_PER_LINE
    return rate * lines / max(1, units)


def build_library(
    name: str,
    lib: Path,
    compiler: str,
    flags: tuple[str, ...] | list[str],
    units: list[str],
    suffix: str,
    libraries: tuple[str, ...] = ("-lm",),
    headers: dict[str, str] | None = None,
) -> None:
    """Compile the translation ``units`` of library ``name`` into ``lib`` (atomically:
    parallel workers never load a half-written library), saying so on a line of its own
    with the time it should take, and log the time it took. A process that needs a library
    another one is compiling waits for it rather than compiling it again."""
    with exclusive(lib.with_suffix(".lock")):
        if lib.exists():  # another process compiled it while this one waited
            return
        lines = sum(u.count("\n") for u in units)
        cores = len(units)
        announce(
            f"compiling {name} (first use on this machine, ~{expected_seconds(lines, cores):.0f} s"
            f" expected{f', {cores} units in parallel' if cores > 1 else ''}) ..."
        )
        start = time.perf_counter()
        part = lib.with_suffix(f".{os.getpid()}.part")
        with tempfile.TemporaryDirectory() as tmp:
            for file, text in (headers or {}).items():
                (Path(tmp) / file).write_text(text)
            compile_units(compiler, units, Path(tmp), suffix, flags, part, libraries)
        part.replace(lib)
        seconds = time.perf_counter() - start
        record = {"name": name, "lines": lines, "units": cores, "seconds": seconds}
        with open(cache_dir() / _LOG, "a") as log:
            log.write(json.dumps(record) + "\n")
        announce(f"compiled {name} in {seconds:.1f} s, cached in {lib.parent}")


@contextlib.contextmanager
def exclusive(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``path`` (a no-op where there is no ``fcntl``)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: parallel workers may compile the same library twice
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def announce(message: str) -> None:
    """``message`` on a line of its own on stderr, above any progress bar that is running
    (tqdm's write), never inside its line."""
    from tqdm import tqdm

    tqdm.write(message, file=sys.stderr)
    sys.stderr.flush()


class BufferCall:
    """Zero-copy calls of a CasADi function on preallocated numpy arrays.

    Inputs and outputs are float64 arrays in CasADi's column-major layout: pass
    matrices as their transposes in C order (``a.T`` of a C-contiguous array is that).
    """

    def __init__(self, fn: cs.Function, sparse: bool = False) -> None:
        """``sparse``: each output is the flat array of its nonzeros (column-major), for
        functions with sparse outputs (e.g. QP matrices); otherwise dense arrays shaped
        as the transposes of CasADi's matrices."""
        self.fn = fn
        self._buf, self._eval = fn.buffer()
        self.outputs = [
            np.zeros(fn.nnz_out(i)) if sparse else np.zeros(fn.size_out(i)[::-1])
            for i in range(fn.n_out())
        ]
        for i, out in enumerate(self.outputs):
            self._buf.set_res(i, memoryview(out))
        self._inputs: list[np.ndarray | None] = [None] * fn.n_in()

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        for i, a in enumerate(args):
            if self._inputs[i] is not a:  # re-binding costs, skip when unchanged
                if not (a.flags.c_contiguous and a.dtype == np.float64):
                    raise ValueError(f"input {i} of {self.fn.name()} must be C-contiguous float64")
                self._buf.set_arg(i, memoryview(a))
                self._inputs[i] = a
        self._eval()
        return self.outputs

    def bind_output(self, i: int, array: np.ndarray) -> None:
        """Output ``i`` written into ``array`` from now on: a C-contiguous float64 array of
        as many entries (e.g. a view into a larger array the caller hands on), in the
        output's layout; ``outputs[i]`` becomes its view of the output's shape."""
        shape = self.outputs[i].shape
        if array.size != self.outputs[i].size or not (
            array.flags.c_contiguous and array.dtype == np.float64
        ):
            raise ValueError(
                f"output {i} of {self.fn.name()} needs a C-contiguous float64 array of "
                f"{self.outputs[i].size} entries, got {array.dtype} {array.shape}"
            )
        self.outputs[i] = array.reshape(shape)
        self._buf.set_res(i, memoryview(self.outputs[i]))

    def again(self) -> None:
        """Evaluate on the arrays bound by the last call (their contents may have been
        rewritten in place since); results in ``outputs``. Saves the argument loop on
        hot paths that refill one input buffer per call."""
        self._eval()


class NamespacePickled:
    """Pickling for array code over a namespace ``xp`` (numpy, or CuPy): the pickle names
    the namespace (a module is no state) and unpickling imports it again."""

    xp: Any

    def __getstate__(self) -> dict:
        return {**self.__dict__, "xp": self.xp.__name__}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({**state, "xp": importlib.import_module(state["xp"])})

    def host(self, a: Any) -> np.ndarray:
        """A numpy array of ``a`` (a copy off the device where ``xp`` is not numpy)."""
        return np.asarray(a) if self.xp is np else self.xp.asnumpy(a)


class RebuiltOnUnpickle:
    """Pickling and deep copies for objects that hold compiled CasADi functions.

    Compiled functions are SWIG objects that cannot be pickled, and a shallow copy would
    share their bound buffers. The pickle holds the constructor's arguments
    (``self._init_args``, set by the constructor) and the plain attributes, less those
    named in ``_rebuilt``; unpickling calls the constructor again (the libraries come
    from the disk cache, the symbolic graphs from the process cache) and restores the
    attributes, copying arrays into the rebuilt ones in place, since compiled calls and
    views are bound to those. ``copy.copy`` makes the same independent copy.
    """

    _init_args: tuple
    _rebuilt: tuple[str, ...] = ()

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in self._rebuilt}

    def __setstate__(self, state: dict) -> None:
        self.__init__(*state["_init_args"])
        for key, value in state.items():
            current = self.__dict__.get(key)
            if (
                isinstance(current, np.ndarray)
                and isinstance(value, np.ndarray)
                and current.shape == value.shape
                and current.dtype == value.dtype
            ):
                current[...] = value
            else:
                self.__dict__[key] = value

    def __copy__(self):
        return copy.deepcopy(self)
