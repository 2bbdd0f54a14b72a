"""The Kalman filter's measurement update on small fixed-size matrices, unrolled for XLA:CPU.

``update`` is the Joseph-form update with a soft innovation gate that jaxmodel/kalman.py (US 4,680,715) runs for the
compass, the map and the fixes; ``small_matmul`` and ``sparse_left_matmul`` are the small products it and
``kalman.predict`` are written in (sums of broadcast products, no dot and no reduce: see ``small_matmul``), ``_inv``
the closed-form inverse of the innovation covariance (one or two measurements).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .packed import value_once

MAX_GATE_SCALE = 1.0e12
"""Largest inflation of R by the soft gate (keeps K R K^T finite for absurd innovations)."""


def small_matmul(a, b):
    """Product of small matrices (1-D operands as in ``@``), unrolled over the inner dimension.

    Written as a sum of broadcast products with no dot or reduce: under vmap, XLA:CPU turns
    batched 5x5 dots and multiply-reduce chains into library fusions that cost ~70 us per step
    for 64 drives; the unrolled form fuses into plain loops (bench/bench_modes.py).
    """
    if a.ndim == 1:
        return sum(a[k] * b[k] for k in range(a.shape[0]))
    if b.ndim == 1:
        return sum(a[:, k] * b[k] for k in range(b.shape[0]))
    return sum(a[:, k, None] * b[None, k, :] for k in range(a.shape[1]))


def sparse_left_matmul(pattern, a, m):
    """a @ m for a small matrix ``a`` whose nonzeros lie in the static bool ``pattern``: each row
    a sum of scaled rows of m (no dot, no reduce; see small_matmul)."""
    rows = []
    for i in range(pattern.shape[0]):
        terms = [a[i, j] * m[j] for j in range(pattern.shape[1]) if pattern[i, j]]
        rows.append(sum(terms) if terms else jnp.zeros_like(m[0]))
    return jnp.stack(rows)


def _inv(s):
    """Inverse of a 1x1 or 2x2 SPD matrix (closed form)."""
    if s.shape[-1] == 1:
        return 1.0 / s
    a, b, c, d = s[0, 0], s[0, 1], s[1, 0], s[1, 1]
    det = a * d - b * c
    return jnp.stack([jnp.stack([d, -b]), jnp.stack([-c, a])]) / det


def update(err, cov, nu, h, r, mask, gate, pattern=None):
    """Measurement update with innovation ``nu`` (m,), H (m, N_STATES), R (m, m); Joseph form.

    ``pattern`` (static bool, shape of H) marks where H may be nonzero; the rest is skipped.  When
    it is None, ``h`` must be concrete (a numpy array or a constant) and its zeros are the pattern.
    ``gate`` > 0: soft gate, R is scaled by max(1, d^2 / gate^2), d^2 = nu^T S^-1 nu (S without
    the scaling); gate <= 0 disables it.  ``mask`` (bool) False leaves (err, cov) as they are.
    Returns (err, cov, d^2).
    """
    if pattern is None:
        h = np.asarray(h, dtype=np.float64)
        pattern = h != 0.0
    hj = jnp.asarray(h)
    # computed once (packed.value_once): the innovation, R, d^2 and the gate's scale reach every element of x and P, and
    # XLA:CPU otherwise recomputes their chains (the measurement's, its noise model's) per element; so does P's.  Not
    # K: made a value of its own, it changed 12 % of the headings by 1 ulp (how XLA contracts K nu + x) for 10 % speed.
    nu, r = value_once(nu), value_once(r)
    hp = sparse_left_matmul(pattern, hj, cov)  # H P, (m, N_STATES)
    hph = sparse_left_matmul(pattern, hj, hp.T)  # H P H^T, (m, m)
    s0 = hph + r
    d2 = value_once(small_matmul(small_matmul(nu, _inv(s0)), nu))
    scale = value_once(jnp.where(gate > 0.0, jnp.clip(d2 / jnp.where(gate > 0.0, gate, 1.0) ** 2, 1.0, MAX_GATE_SCALE),
                                 1.0))
    s = hph + scale * r
    k = small_matmul(hp.T, _inv(s))  # (N_STATES, m)
    k = jnp.where(mask, k, 0.0)
    x = err + small_matmul(k, nu)
    # Joseph form (I - K H) P (I - K H)^T + K R K^T, evaluated in factored order with rank-m
    # products (A = I - K H): AP = P - K (H P), then AP A^T = AP - (AP H^T) K^T.
    ap = cov - small_matmul(k, hp)
    aph = sparse_left_matmul(pattern, hj, ap.T).T  # AP H^T, (N_STATES, m)
    p = ap - small_matmul(aph, k.T) + scale * small_matmul(small_matmul(k, r), k.T)
    return x, value_once(0.5 * (p + p.T)), d2
