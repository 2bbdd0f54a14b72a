"""The normal equations of a small least-squares regression, carried sample by sample and solved written out.

Two learners regress on five regressors x_i sample by sample: jaxmodel/soft_iron.py (DELTA on the heading's first two
harmonics and the wheels' turn) and jaxmodel/soft_iron_field.py (ln|B| on 1 and the heading's harmonics).  Each keeps
the upper triangle of its normal matrix, n_ij = sum w x_i x_j (i <= j), and the right-hand side b_i = sum w x_i y as
named scalars of its packed state (``sum_fields``), and solves them by a Cholesky factor written out in elementwise
operations (``cholesky_solve``): the native FMU lowers those, not jnp.linalg's.
"""

from __future__ import annotations

from .angles import safe_sqrt


def pairs(k: int) -> list[tuple[int, int]]:
    """(i, j), i <= j < k: the normal matrix's upper triangle, row by row."""
    return [(i, j) for i in range(k) for j in range(i, k)]


def sum_fields(k: int) -> list[str]:
    """The state's names of the sums for k regressors: n{i}{j} in ``pairs(k)`` order, then b{i}."""
    return [f"n{i}{j}" for i, j in pairs(k)] + [f"b{i}" for i in range(k)]


def normal_matrix(fields, k: int, diagonal):
    """The symmetric k x k matrix (lists) of the sums n{i}{j} in ``fields``, plus ``diagonal[i]`` on its diagonal
    (a ridge prior)."""
    m = [[None] * k for _ in range(k)]
    for i, j in pairs(k):
        m[i][j] = m[j][i] = getattr(fields, f"n{i}{j}") + (diagonal[i] if i == j else 0.0)
    return m


def cholesky_solve(m, rhs):
    """Solve m c = rhs, m symmetric positive definite (k x k lists of arrays), by its Cholesky factor L (m = L L^T).
    Returns (c, y, low): the solution, the forward-solved right-hand side y = L^-1 rhs (so L^T c = y) and L, as
    lists (low[i][j] for j <= i)."""
    k = len(rhs)
    low = [[None] * k for _ in range(k)]
    for j in range(k):
        low[j][j] = safe_sqrt(m[j][j] - sum((low[j][i] * low[j][i] for i in range(j)), 0.0), floor=1e-30)
        for i in range(j + 1, k):
            low[i][j] = (m[i][j] - sum((low[i][n] * low[j][n] for n in range(j)), 0.0)) / low[j][j]
    y = []
    for i in range(k):
        y.append((rhs[i] - sum((low[i][n] * y[n] for n in range(i)), 0.0)) / low[i][i])
    c = [None] * k
    for i in reversed(range(k)):
        c[i] = (y[i] - sum((low[n][i] * c[n] for n in range(i + 1, k)), 0.0)) / low[i][i]
    return c, y, low
