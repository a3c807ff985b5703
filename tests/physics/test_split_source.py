"""Generated C cut into parts and translation units (uvms_env.dynamics.split_source)
computes what CasADi computes, and leaves alone what it cannot cut."""

from __future__ import annotations

from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from uvms_env.dynamics.compiled import find_compiler, generated_source
from uvms_env.dynamics.split_source import (
    compile_units,
    cut_long_functions,
    default_units,
    translation_units,
)

CC = find_compiler()
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler")


def _long_function(name: str, n: int = 8, rounds: int = 12) -> cs.Function:
    """A straight-line SX function of a few thousand statements whose early values are read
    late (as in a reverse-mode Jacobian), so that the cut must carry them across parts."""
    x = cs.SX.sym("x", n)
    values = [cs.sin(x[i]) + x[(i + 1) % n] ** 2 for i in range(n)]
    first = list(values)
    for r in range(rounds):
        values = [
            cs.cos(values[i] * values[(i + r + 1) % n]) + cs.sqrt(1 + values[i] ** 2)
            for i in range(n)
        ]
    out = cs.vertcat(*[v * f for v, f in zip(values, first, strict=True)])
    return cs.Function(name, [x], [out, cs.jacobian(out, x)])


_source = generated_source


def _build(fn: cs.Function, units: list[str], folder: Path) -> cs.Function:
    lib = folder / f"{fn.name()}_{len(units)}.so"
    compile_units(CC, units, folder, ".c", ("-O1", "-fPIC", "-shared"), lib)
    return cs.external(fn.name(), str(lib))


def test_a_cut_function_in_several_units_computes_what_casadi_computes(tmp_path: Path) -> None:
    fn = _long_function("split_probe")
    source = _source(fn)
    cut = cut_long_functions(source, above=500, max_statements=300)
    assert cut.count("_part") > 4  # cut into parts, called in order
    units = translation_units(cut, 2)
    assert len(units) == 2 and "_part" in units[1]
    x = np.random.default_rng(0).uniform(-1, 1, 8)
    want = [np.array(v) for v in fn(x)]
    for built in (_build(fn, [source], tmp_path), _build(fn, units, tmp_path)):
        for got, ref in zip(built(x), want, strict=True):
            np.testing.assert_allclose(np.array(got), ref, rtol=1e-12, atol=1e-12)


def test_short_and_non_straight_line_functions_stay_whole() -> None:
    short = _source(_long_function("split_short", n=3, rounds=2))
    assert cut_long_functions(short, above=10_000) == short
    x = cs.MX.sym("x", 4)
    inner = _long_function("split_inner", n=4, rounds=3)
    looped = cs.Function("split_looped", [x], [inner.map(3, "serial")(cs.repmat(x, 1, 3))[0]])
    source = _source(looped)
    cut = cut_long_functions(source, above=50, max_statements=40)
    # the SX function inside is cut; the MX function with its loop is not
    wrapper = cut[cut.index("static int casadi_f0(") :]
    assert "for (" in wrapper.split("\n}\n", 1)[0]
    assert cut.count("_part") > 1


def test_two_cut_libraries_loaded_together_keep_their_own_parts(tmp_path: Path) -> None:
    # the parts are hidden symbols: two libraries with parts of the same number never mix
    a, b = _long_function("split_a"), _long_function("split_b", rounds=11)
    built = []
    for fn in (a, b):
        units = translation_units(cut_long_functions(_source(fn), 500, 300), 2)
        built.append(_build(fn, units, tmp_path))
    x = np.linspace(-0.5, 0.5, 8)
    for fn, lib in zip((a, b), built, strict=True):
        np.testing.assert_allclose(np.array(lib(x)[0]), np.array(fn(x)[0]), rtol=1e-12)


def test_small_sources_compile_as_one_unit() -> None:
    assert default_units("x\n" * 100) == 1
