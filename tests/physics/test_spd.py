"""The branch-free SPD solves of the simulator's step against numpy's LAPACK."""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from uvms_env.dynamics.spd import spd_inverse, spd_solve


@pytest.mark.parametrize(("n", "m"), [(10, 7), (6, 6), (6, 1)])
def test_spd_solve_equals_lapack_on_spd_matrices(n: int, m: int) -> None:
    # condition numbers up to ~1e5, as the mass matrices' (eigenvalues 1e-3 to ~40)
    a, b = cs.SX.sym("a", n, n), cs.SX.sym("b", n, m)
    solve = cs.Function("solve", [a, b], [spd_solve(a, b)])
    rng = np.random.default_rng(n * m)
    for _ in range(20):
        basis, _ = np.linalg.qr(rng.normal(size=(n, n)))
        spd = basis @ np.diag(np.logspace(-3, 2, n)) @ basis.T
        rhs = rng.normal(size=(n, m))
        expected = np.linalg.solve(spd, rhs)
        got = np.array(solve(spd, rhs))
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_spd_inverse_is_symmetric_and_inverts() -> None:
    a = cs.SX.sym("a", 6, 6)
    inverse = cs.Function("inverse", [a], [spd_inverse(a)])
    rng = np.random.default_rng(0)
    x = rng.normal(size=(6, 6))
    spd = x @ x.T + np.eye(6)
    got = np.array(inverse(spd))
    np.testing.assert_array_equal(got, got.T)
    np.testing.assert_allclose(got @ spd, np.eye(6), atol=1e-12)


def test_spd_solve_reads_the_lower_triangle_only() -> None:
    a, b = cs.SX.sym("a", 4, 4), cs.SX.sym("b", 4, 1)
    upper = {(i, j) for i in range(4) for j in range(i + 1, 4)}
    used = cs.symvar(spd_solve(a, b))
    names = {v.name() for v in used}
    assert not any(str(a[i, j]) in names for i, j in upper)
