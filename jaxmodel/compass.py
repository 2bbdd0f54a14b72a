"""Compass heading and its error bound, US 4,734,863 FIG. 8A and FIG. 8C."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import safe_div, wrap
from .params import DEVIATION_TABLE_SIZE, deg, field_magnitude_given

MIN_FIELD = 1e-9
"""A horizontal field weaker than this (compass units) carries no direction: the sample is skipped."""

MAX_FIELD = 1e100
"""A compass component larger than this (compass units) is a fault: the sample is skipped."""


def deviation(raw_heading, deviation_deg):
    """Deviation (rad) at raw heading A, periodic linear interpolation of the 36-entry table (FIG. 8A block 4).

    Between the two table entries around A: (1 - f) dev[i] + f dev[i + 1 mod 36], u = A / 10 deg,
    i = floor(u), f = u - i.  Read at two entries rather than as a sum of 36 hat functions: the
    native FMU's step is 15 % shorter (C master); XLA:CPU is a few per cent slower with the gather.
    """
    n = DEVIATION_TABLE_SIZE
    u = jnp.mod(raw_heading, 2.0 * jnp.pi) / deg(360.0 / n)  # in [0, n]
    i = jnp.clip(jnp.floor(u), 0.0, n - 1.0)
    f = u - i
    i0 = i.astype(jnp.int32)
    i1 = jnp.where(i0 == n - 1, 0, i0 + 1)
    table = jnp.asarray(deviation_deg, jnp.float64)
    return deg(table[..., i0] * (1.0 - f) + table[..., i1] * f)


def compass_heading(params, compass_x, compass_y):
    """H_C = atan2(Y - Y0, X - X0) + deviation - R + V (FIG. 8A), wrapped; plus |B| and validity.

    Returns (H_C [rad], B_M [compass units], valid [bool]).  A non-finite component, both raw
    components exactly 0, or a field weaker than MIN_FIELD makes the sample invalid; H_C is then 0
    (and must be ignored).
    """
    x = compass_x - params.X0
    y = compass_y - params.Y0
    # Components beyond MAX_FIELD are sensor faults (and would overflow |B|^2 and the learned mean).
    valid = jnp.isfinite(x) & jnp.isfinite(y) & (jnp.abs(x) < MAX_FIELD) & (jnp.abs(y) < MAX_FIELD)
    # Loggers and gateways fill a missing reading with zeros; no magnetometer in the earth's field reads exactly 0 on
    # both axes.  Less the hard iron, such a sample was a steady field of |(X0, Y0)|, and 30 s of it restarted the
    # filter from it as lost (independent seeds 50-57: 17 deg mean added RMSE, docs/tuning.md stop 52).
    valid = valid & ~((compass_x == 0.0) & (compass_y == 0.0))
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


FIELD_BINS = 12
"""Headings at which the expected field magnitude B_E is learned (every 30°, interpolated)."""
FIELD_PRIOR_M = 20.0
"""Metres of the drive-wide mean that a heading bin starts from (so an unseen heading has a B_E)."""


def _bin_weights(heading):
    """Periodic hat weights (FIELD_BINS,) of a heading (rad) over the bins."""
    u = jnp.mod(heading, 2.0 * jnp.pi) / (2.0 * jnp.pi / FIELD_BINS)
    nodes = jnp.arange(FIELD_BINS, dtype=jnp.float64)
    d = jnp.abs(jnp.expand_dims(u, -1) - nodes)
    d = jnp.minimum(d, FIELD_BINS - d)
    return jnp.maximum(1.0 - d, 0.0)


def expected_field(params, field_sum, field_weight, heading, b_m):
    """B_E at ``heading`` (US 4,734,863 FIG. 8C, col. 9: "the magnitude ... for each of those known headings").

    The parameter field_magnitude when > 0; else learned on the drive: per heading bin the
    distance-weighted mean of |B| (``learn_field``), each bin pulled towards the drive-wide mean
    by FIELD_PRIOR_M metres, interpolated between bins.  Before anything is learned: |B| itself.
    """
    total_w = jnp.sum(field_weight)
    overall = safe_div(jnp.sum(field_sum), total_w, eps=1e-9, fallback=1.0)
    overall = jnp.where(total_w > 1e-9, overall, b_m)
    per_bin = (field_sum + FIELD_PRIOR_M * overall) / (field_weight + FIELD_PRIOR_M)
    learned = jnp.sum(_bin_weights(heading) * per_bin)
    return jnp.where(field_magnitude_given(params), params.field_magnitude, learned)


def learn_field(params, field_sum, field_weight, heading, b_m, b_e, d_t, clean):
    """Distance-weighted learning of |B| per heading bin (claim 13), with forgetting over field_memory_m.

    Only samples while moving (weight d_t), with a valid compass that the heading filter did not
    judge disturbed (``clean``) and within field_learn_gate (relative) of the current B_E once
    the bin holds FIELD_PRIOR_M metres, so standstill, anomalies and a parked truck do not teach it.
    """
    w = _bin_weights(heading)
    near = jnp.abs(safe_div(b_m - b_e, b_e, fallback=1.0)) < params.field_learn_gate
    young = field_weight < FIELD_PRIOR_M
    use = clean & (d_t > 0.0) & (near | young)
    w = jnp.where(use, w, 0.0)
    inc = d_t * w
    # A bin forgets over field_memory_m metres in proportion to its hat weight: one exp per sample
    # rather than one per bin (the same for a weight of 0 or 1; a bin between forgets linearly).
    forget = 1.0 - w * -jnp.expm1(-d_t / params.field_memory_m)
    return forget * field_sum + inc * b_m, forget * field_weight + inc


STALE_TURN_DEG = 5.0
"""A compass reading repeated exactly while the wheels turned by more than this (deg, net) is stale
(``stale_check``)."""


class StaleState(NamedTuple):
    """The last finite raw compass reading (compass units), the wheels' net turn (rad, alpha summed) since it
    last changed, and the seconds (the samples' dt summed) since the last fresh reading (``reading_interval``)."""
    last_x: jnp.ndarray
    last_y: jnp.ndarray
    turn: jnp.ndarray
    since_s: jnp.ndarray


def init_stale_state() -> StaleState:
    z = jnp.zeros((), jnp.float64)
    return StaleState(z, z, z, z)


def stale_check(state: StaleState, compass_x, compass_y, alpha):
    """Whether this raw reading repeats the last one exactly while the wheels turned by more than STALE_TURN_DEG.

    The net turn: on a straight road the wheel heading's pulse quantization jitters by a pulse each way, and a
    noise-free compass repeats itself there (|alpha| summed made a synthetic straight stale within a second).

    A logger or gateway that lost the magnetometer's messages repeats its last value (a compass sampled slower than
    the log does so between its updates); a magnetometer's reading changes by microteslas when the car turns 5 deg
    in a 20 µT field.  Held for a turn, it is wrong by the turn, steadily, and 60 s of it restarted the filter from
    it as lost (independent seeds 50-57: 12 deg mean added RMSE, docs/tuning.md stop 52).  Standing or straight, a
    repeated reading is still a reading.  Returns (new state, stale [bool]).
    """
    same = (compass_x == state.last_x) & (compass_y == state.last_y)
    turn = jnp.where(same, state.turn + alpha, 0.0)
    keep = jnp.isfinite(compass_x) & jnp.isfinite(compass_y)
    new = StaleState(jnp.where(keep, compass_x, state.last_x), jnp.where(keep, compass_y, state.last_y), turn,
                     state.since_s)
    return new, jnp.abs(turn) > deg(STALE_TURN_DEG)


def reading_interval(state: StaleState, dt, fresh):
    """(new state, interval s): the seconds since the previous fresh compass reading, this sample's ``dt`` (s)
    included, and the count restarted where this sample's reading is ``fresh`` (finite, not stale; bool).

    A compass logged slower than the wheels (a 1-Hz magnetometer in a 10-Hz log, NaN between its readings) gives one
    reading per interval: ``compass_noise.samples_per_measurement`` counts it for the interval it stands for.  Every
    sample fresh: the interval is ``dt`` itself."""
    interval = state.since_s + dt
    return state._replace(since_s=jnp.where(fresh, 0.0, interval)), interval
