"""Solves with symmetric positive definite matrices as branch-free CasADi expressions.

The simulator's step solves with a robot's mass matrix (10 x 10), its operational-space
inertia (6 x 6) and the object's coupled inertia (6 x 6), all symmetric positive definite,
inside SX functions that also run one environment per SIMD lane or GPU thread: no pivoting
and no data-dependent branch. ``cs.solve`` on SX expands a QR factorization; an LDL^T
factorization needs no pivoting on an SPD matrix and about half its operations (a 10 x 10
solve with 7 right-hand sides: 2,065 against 4,325).

May import: casadi.
"""

from __future__ import annotations

import casadi as cs


def spd_solve(a: cs.SX, b: cs.SX) -> cs.SX:
    """a^-1 b for a symmetric positive definite ``a`` (n x n; its lower triangle is read)
    and ``b`` (n x m), by a := L D L^T and two triangular solves."""
    n, m = a.shape[0], b.shape[1]
    if a.shape != (n, n) or b.shape[0] != n:
        raise ValueError(
            f"spd_solve needs a square a and as many rows in b, got {a.shape}, {b.shape}"
        )
    low: list[list[cs.SX]] = [[cs.SX(0)] * n for _ in range(n)]
    diag: list[cs.SX] = []
    for j in range(n):
        diag.append(a[j, j] - _dot([low[j][k] * low[j][k] for k in range(j)], diag))
        for i in range(j + 1, n):
            low[i][j] = (a[i, j] - _dot([low[i][k] * low[j][k] for k in range(j)], diag)) / diag[j]
    columns = []
    for c in range(m):
        y: list[cs.SX] = []
        for i in range(n):  # L y = b
            y.append(b[i, c] - _dot(low[i][:i], y))
        x: list[cs.SX] = [cs.SX(0)] * n
        for i in reversed(range(n)):  # L^T x = D^-1 y
            x[i] = y[i] / diag[i] - _dot([low[k][i] for k in range(i + 1, n)], x[i + 1 :])
        columns.append(cs.vertcat(*x))
    return cs.horzcat(*columns)


def spd_inverse(a: cs.SX) -> cs.SX:
    """a^-1 of a symmetric positive definite ``a``, exactly symmetric."""
    inverse = spd_solve(a, cs.SX.eye(a.shape[0]))
    return 0.5 * (inverse + inverse.T)


def _dot(u: list[cs.SX], v: list[cs.SX]) -> cs.SX:
    # over u's length: below the diagonal, v (the pivots so far) already holds column j's
    total = cs.SX(0)
    for p, q in zip(u, v, strict=False):
        total = total + p * q
    return total
