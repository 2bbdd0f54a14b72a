"""Small Kalman algebra unrolled into scalars at trace time.

The robust F-DELTA (``offset_filter``) keeps its six states and the upper triangle of their covariance as fields
of one packed vector (``packed.py``).  Inside the vmapped scan XLA:CPU runs each tiny matmul as its own kernel, and
a dense (5, 5) form on broadcasts was no faster (docs/tuning.md, "Throughput, stop 22"), so its algebra is written
on nested lists of scalars.  Rows given as Python numbers (the structural 0s and 1s of a measurement vector) emit no
operation.  The Kalman mode (``kalman.py``) keeps a dense covariance and does not use this: its algebra, unrolled
over small dense matrices instead, is ``kalman_update.py``.
"""

from __future__ import annotations

import jax.numpy as jnp


def upper_indices(n):
    """(i, j) of the upper triangle of an n x n matrix, row by row: the order of the p_ij fields."""
    return tuple((i, j) for i in range(n) for j in range(i, n))


def covariance(fields, n):
    """P (n x n) as a symmetric nested list of the scalars ``fields.p{i}{j}`` (i <= j)."""
    P = [[None] * n for _ in range(n)]
    for i, j in upper_indices(n):
        P[i][j] = P[j][i] = getattr(fields, f"p{i}{j}")
    return P


def upper(P):
    """The p_ij fields (i <= j) of a nested-list covariance, as a dict."""
    return {f"p{i}{j}": P[i][j] for i, j in upper_indices(len(P))}


def _is_constant(v, value):
    """Whether v is the Python number ``value`` (a structural 0 or 1, known at trace time)."""
    return isinstance(v, (int, float)) and v == value


def scaled(v, factor):
    """v times factor, skipping a factor of exactly 1 (one operation less per step)."""
    return v if _is_constant(factor, 1) else v * factor


def dot(row, column):
    """sum row[m] column[m], skipping the structural zeros and ones (Python numbers) of ``row``."""
    terms = [scaled(c, r) for r, c in zip(row, column) if not _is_constant(r, 0)]
    return sum(terms[1:], terms[0])


def projected(P, h):
    """(P h, h^T P h) for a measurement row ``h`` (a list; Python 0s and 1s cost nothing)."""
    ph = [dot(h, row) for row in P]
    return ph, dot(h, ph)


def gated_scalar_update(x, P, ph, p_hh, nu, r, gate2):
    """One scalar Kalman update with a soft innovation gate: the measurement variance ``r`` is inflated by
    max(1, nu^2 / (gate2 (h P h + r))), so that an innovation beyond sqrt(gate2) of its sigmas counts as
    proportionally less instead of pulling the state by its full gain.

    x: the states (list of n scalars); P: their covariance (nested list, ``covariance``); ph, p_hh: ``projected``
    for the measurement row h; nu: the innovation; r: the measurement's variance before the gate.
    Returns (x + K nu as a list, the p_ij fields of (I - K h^T) P as a dict, the gain K as a list)."""
    r = r * jnp.maximum(1.0, nu ** 2 / (gate2 * (p_hh + r)))
    inv = 1.0 / (p_hh + r)
    gain = [v * inv for v in ph]
    new_x = [v + g * nu for v, g in zip(x, gain)]
    new_p = {f"p{i}{j}": P[i][j] - gain[i] * ph[j] for i, j in upper_indices(len(x))}
    return new_x, new_p, gain
