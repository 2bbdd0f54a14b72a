"""A shifted hard iron found from the wheels' heading while the heading filter rejects the compass.

US 4,734,863 FIG. 8A block 2 subtracts fixed compass offsets X0, Y0, found at calibration.  A vehicle's
magnetisation can change while it drives (a magnetised tool in the boot, a seat motor, a repair): the offsets
jump by a few µT and the compass then reads a heading-dependent error (3-6 µT on a 20 µT field: 9-17 deg).  The
heading filter rejects it (offset_filter.update's hardening), and it stays rejected for the rest of the drive.

Where the seed is silent (our extension): while the compass is rejected and the wheels do not drift, the fused
heading EH runs on the wheels alone, which are good to about a degree over kilometres.  The field the compass
should read at EH is then known: B_E at the raw angle A_exp that gives EH, so each rejected sample gives the
offset's change directly,

    r = (X - X0, Y - Y0) - B_E (cos A_exp, sin A_exp),   A_exp = A - (H_C - EH),

(A = atan2(Y - Y0, X - X0) the raw angle; compass units).  A shifted hard iron is fixed in the vehicle: r stays
the same vector while the vehicle turns.  An anomaly, a bridge or a car park is fixed in the world: in the
vehicle's frame it turns with the heading, and it ends within metres to hundreds of metres.  So r is averaged over
the rejected samples (forgetting over SHIFT_MEMORY_M of them), and the offsets move by the mean only when

* the samples hold SHIFT_MIN_M metres,
* they were taken over headings spread at least as much as an arc of SHIFT_MIN_TURN_DEG (the mean resultant of
  the heading, as in jaxmodel/hard_iron.py),
* their scatter about the mean is below SHIFT_MAX_SCATTER of B_E, and
* the mean is beyond SHIFT_MIN_CHANGE of B_E (~6 deg at its worst heading: smaller errors are the heading
  filter's to weigh; a soft iron's 2-5 deg and an error of EH itself read as such vectors over a short arc), and
* the mean points more than SHIFT_AXIS_DEG away from the vehicle's forward axis.  A grade is fixed in the vehicle
  too: a pitch puts the vertical field on the forward axis (5 % on a 45 µT vertical field: 2.2 µT) for 300-1200 m
  of road, and the heading filter's tilt state already models it.  A shift along that axis is left to the filter.

Then the sums restart.  The residual reads B_E per heading (claim 13), which a drive started in a garage learns
from the garage's scaled field: jaxmodel/model.py restarts B_E when the heading filter, lost, restarts its heading
(the compass it started from was disturbed, and so was the field learned from it).

Measured on the scenario matrix (stop 36, docs/tuning.md): hard-iron shift drives of seeds 101-109 1.52 -> 1.05 deg
(geometric mean), hills unchanged (1.27 deg on 101-103).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import safe_div, safe_sqrt, wrap
from .hard_iron import resultant_of_arc

SHIFT_MEMORY_M = 1000.0
"""Rejected metres over which the residual sums forget (m)."""
SHIFT_MIN_M = 150.0
"""Rejected metres the sums must hold before the offsets move (m)."""
SHIFT_MIN_TURN_DEG = 45.0
"""Headings of the rejected samples must spread at least as an arc of this width (deg)."""
SHIFT_MAX_SCATTER = 0.08
"""RMS scatter of the residuals about their mean, relative to B_E, below which they are one vector."""
SHIFT_MIN_CHANGE = 0.1
"""A mean residual smaller than this (relative to B_E) moves nothing."""
SHIFT_AXIS_DEG = 30.0
"""A mean residual within this of the forward axis (deg) moves nothing: a grade's dip error (module doc)."""
SHIFT_MAX_TURN_RATE = 0.1
"""Samples taken while turning faster than this (rad/s) are not used: the car rolls, and the vertical field leaks
into the lateral axis (a 3 deg roll on a 45 µT vertical field: 2.4 µT)."""


class ShiftState(NamedTuple):
    """Offsets' change learned so far (ox, oy; compass units) and the forgetful sums of the rejected samples'
    residuals: weight w (m), sx, sy (residual x w), sq (|residual|^2 x w), sc, ss (cos / sin of EH x w)."""

    ox: jnp.ndarray
    oy: jnp.ndarray
    w: jnp.ndarray
    sx: jnp.ndarray
    sy: jnp.ndarray
    sq: jnp.ndarray
    sc: jnp.ndarray
    ss: jnp.ndarray


def init_shift_state() -> ShiftState:
    z = jnp.zeros((), jnp.float64)
    return ShiftState(z, z, z, z, z, z, z, z)


def update(state: ShiftState, compass_x, compass_y, h_c, heading, b_e, d_t, use, rotation=0.0):
    """Learn from one sample: the offset-corrected components ``compass_x``, ``compass_y`` (compass units, the
    parameters' X0/Y0 and ``state``'s change already taken out), their heading H_C (rad), the fused heading EH
    (rad), B_E (compass units), the distance d_t (m), ``use`` (bool): the compass is valid and rejected, the
    wheels do not drift, the vehicle does not turn fast; ``rotation`` (rad) the mounting rotation R, which turns
    the vehicle's forward axis in the compass's frame.  Returns the new state (ox, oy moved when the module
    doc's conditions hold)."""
    # Double-where: a NaN or zero sample must not reach arctan2 or the sums even on the branch not taken (its
    # gradient would be NaN times zero).
    valid = (jnp.isfinite(compass_x) & jnp.isfinite(compass_y) & jnp.isfinite(heading) & jnp.isfinite(b_e)
             & (compass_x * compass_x + compass_y * compass_y > 1e-12))
    use = use & valid
    compass_x, compass_y = jnp.where(valid, compass_x, 1.0), jnp.where(valid, compass_y, 0.0)
    heading, b_e = jnp.where(valid, heading, 0.0), jnp.where(valid, b_e, 1.0)
    raw = jnp.arctan2(compass_y, compass_x)
    expected = raw - wrap(h_c - heading)
    rx = compass_x - b_e * jnp.cos(expected)
    ry = compass_y - b_e * jnp.sin(expected)
    ok = use & jnp.isfinite(rx) & jnp.isfinite(ry) & (d_t > 0.0)
    weight = jnp.where(ok, d_t, 0.0)
    forget = jnp.exp(-weight / SHIFT_MEMORY_M)
    rx, ry = jnp.where(ok, rx, 0.0), jnp.where(ok, ry, 0.0)
    w = forget * state.w + weight
    sx = forget * state.sx + weight * rx
    sy = forget * state.sy + weight * ry
    sq = forget * state.sq + weight * (rx * rx + ry * ry)
    sc = forget * state.sc + weight * jnp.cos(heading)
    ss = forget * state.ss + weight * jnp.sin(heading)
    mx, my = safe_div(sx, w, eps=1e-9, fallback=0.0), safe_div(sy, w, eps=1e-9, fallback=0.0)
    scatter = safe_sqrt(jnp.maximum(safe_div(sq, w, eps=1e-9, fallback=0.0) - mx * mx - my * my, 0.0))
    resultant = safe_div(safe_sqrt(sc * sc + ss * ss), w, eps=1e-9, fallback=1.0)
    shift = safe_sqrt(mx * mx + my * my)
    move = (ok & (w > SHIFT_MIN_M) & (resultant < resultant_of_arc(jnp.radians(SHIFT_MIN_TURN_DEG)))
            & (scatter < SHIFT_MAX_SCATTER * b_e) & (shift > SHIFT_MIN_CHANGE * b_e)
            & (jnp.abs(my * jnp.cos(rotation) - mx * jnp.sin(rotation)) > jnp.sin(jnp.radians(SHIFT_AXIS_DEG)) * shift))
    keep = jnp.where(move, 0.0, 1.0)
    return ShiftState(ox=state.ox + jnp.where(move, mx, 0.0), oy=state.oy + jnp.where(move, my, 0.0),
                      w=keep * w, sx=keep * sx, sy=keep * sy, sq=keep * sq, sc=keep * sc, ss=keep * ss)
