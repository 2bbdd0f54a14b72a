"""Wheel heading change and the Ackerman effective track, US 4,788,645.

* eq. (8):  dtheta_w = dD / (T (1 + a V^2))
* eq. (14): T_E = T_F [P + (1-P) sqrt(0.5 + 0.5 sqrt(1 - c^2/(1 - 0.25 c^2) (2B/T_F)^2))],
  c = dD/AD, the curvature of turn (dimensionless: track over turn radius).
* claims 15-16: T_E read from a table addressed by the curvature.

The inner radicand of eq. (14) reaches zero at the geometric maximum curvature
c_max = 1/sqrt((2B/T_F)^2 + 0.25) (~0.28 for a car).  Curvature is clipped at
``curvature_clip * c_max`` before evaluation, so neither value nor gradient is ever
NaN, and the gradient with respect to P, B, T_F stays bounded.
"""

from __future__ import annotations

import jax.numpy as jnp

from .angles import safe_div, safe_sqrt

TABLE_SIZE = 2049
"""Nodes of the effective-track table.  The table is addressed by c^2 (eq. 14 depends on c
only through c^2), which keeps linear interpolation within 3.4e-7 relative of the closed form
up to 0.98 c_max (measured: see tests/test_track.py)."""


def max_curvature(B, T_F):
    """Geometric maximum of dD/AD where the inner square root of eq. (14) vanishes."""
    k = (2.0 * B / T_F) ** 2
    return 1.0 / jnp.sqrt(k + 0.25)


def clip_curvature(c, B, T_F, clip_fraction):
    """|c| clipped to clip_fraction * c_max (US 4,788,645: realizable curvatures end near 0.27)."""
    c_lim = clip_fraction * max_curvature(B, T_F)
    return jnp.minimum(jnp.abs(c), c_lim)


def effective_track(c, P, B, T_F, clip_fraction=0.98):
    """T_E(c; P, B, T_F), US 4,788,645 eq. (14), closed form. c = dD/AD (any sign), result in m."""
    c = clip_curvature(c, B, T_F, clip_fraction)
    return _effective_track_of_c2(c * c, P, B, T_F)


def _effective_track_of_c2(c2, P, B, T_F):
    """Eq. (14) as a function of c^2 (no square root of c: smooth at c = 0 for the table)."""
    q = c2 / (1.0 - 0.25 * c2) * (2.0 * B / T_F) ** 2
    inner = safe_sqrt(1.0 - q)
    return T_F * (P + (1.0 - P) * jnp.sqrt(0.5 + 0.5 * inner))


def effective_track_table(P, B, T_F, clip_fraction=0.98, size=TABLE_SIZE):
    """Table of claims 15-16: (c2_max, T_E at c^2 = linspace(0, c2_max, size)). Differentiable in P, B, T_F."""
    c_lim = clip_fraction * max_curvature(B, T_F)
    c2_nodes = jnp.linspace(0.0, 1.0, size) * c_lim**2
    values = _effective_track_of_c2(c2_nodes, P, B, T_F)
    return c2_nodes[-1], values


def effective_track_lookup(c, table):
    """T_E from the table of ``effective_track_table`` by linear interpolation in c^2 (claims 15-16)."""
    c2_max, values = table
    n = values.shape[-1] - 1
    u = jnp.clip(safe_div(c * c, c2_max) * n, 0.0, float(n))
    i = jnp.clip(jnp.floor(u), 0, n - 1).astype(jnp.int32)
    w = u - i
    return values[i] * (1.0 - w) + values[i + 1] * w


def velocity_corrected(dD, a, V):
    """dD / (1 + a V^2) (m): eq. (8)'s wheel turn times T, summed over an interval before dividing by its T_E."""
    return dD / (1.0 + a * V * V)


def wheel_heading_change(dD, T, a, V):
    """dtheta_w = dD / (T (1 + a V^2)), US 4,788,645 eq. (8). dD in m (left minus right), T in m, V in m/s; rad."""
    return velocity_corrected(dD, a, V) / T
