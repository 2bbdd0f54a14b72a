"""Compass heading and its error bound, US 4,734,863 FIG. 8A and FIG. 8C."""

from __future__ import annotations

import jax.numpy as jnp

from .angles import safe_div, wrap
from .params import DEVIATION_TABLE_SIZE, deg

MIN_FIELD = 1e-9
"""A horizontal field weaker than this (compass units) carries no direction: the sample is skipped."""

MAX_FIELD = 1e100
"""A compass component larger than this (compass units) is a fault: the sample is skipped."""


def deviation(raw_heading, deviation_deg):
    """Deviation (rad) at raw heading A, periodic linear interpolation of the 36-entry table (FIG. 8A block 4).

    Written as a sum of hat functions rather than a gather: one fused elementwise kernel,
    measurably cheaper than two gathers inside a vmapped scan on XLA:CPU.
    """
    n = DEVIATION_TABLE_SIZE
    u = jnp.mod(raw_heading, 2.0 * jnp.pi) / deg(360.0 / n)  # in [0, n)
    nodes = jnp.arange(n, dtype=jnp.float64)
    distance = jnp.abs(jnp.expand_dims(u, -1) - nodes)
    distance = jnp.minimum(distance, n - distance)  # periodic
    weights = jnp.maximum(1.0 - distance, 0.0)
    return deg(jnp.sum(weights * deviation_deg, axis=-1))


def compass_heading(params, compass_x, compass_y):
    """H_C = atan2(Y - Y0, X - X0) + deviation - R + V (FIG. 8A), wrapped; plus |B| and validity.

    Returns (H_C [rad], B_M [compass units], valid [bool]).  A non-finite component or a
    field weaker than MIN_FIELD makes the sample invalid; H_C is then 0 (and must be ignored).
    """
    x = compass_x - params.X0
    y = compass_y - params.Y0
    # Components beyond MAX_FIELD are sensor faults (and would overflow |B|^2 and the learned mean).
    valid = jnp.isfinite(x) & jnp.isfinite(y) & (jnp.abs(x) < MAX_FIELD) & (jnp.abs(y) < MAX_FIELD)
    x = jnp.where(valid, x, 1.0)
    y = jnp.where(valid, y, 0.0)
    b2 = x * x + y * y
    valid = valid & (b2 > MIN_FIELD**2)
    b_m = jnp.sqrt(jnp.where(valid, b2, 1.0))
    x = jnp.where(valid, x, 1.0)
    raw = jnp.arctan2(y, x)
    h_c = wrap(raw + deviation(raw, params.deviation_deg) - deg(params.rotation_deg) + deg(params.variation_deg))
    return jnp.where(valid, h_c, 0.0), jnp.where(valid, b_m, 0.0), valid


def compass_error_bound(params, b_m, b_e):
    """E_C = |B_M - B_E| / B_E x 60 deg (FIG. 8C blocks 3-5), floored; rad."""
    d = jnp.abs(safe_div(b_m - b_e, b_e, fallback=1.0))
    return jnp.maximum(d * deg(params.compass_error_scale_deg), deg(params.compass_error_floor_deg))
