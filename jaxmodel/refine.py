"""Online refinement of the velocity coefficient a, US 4,788,645 eq. (9)-(13).

Over a turn, the wheel heading change dtheta_w is compared with the compass heading change
dtheta_C.  Both are measured through the compass-minus-wheel offset off = H_C - H_W averaged
over the straight stretches before and after the turn, so
dtheta_C - dtheta_w = off_after - off_before, and single noisy compass samples do not enter.

ERROR = dtheta_w - dtheta_C if dtheta_w >= 0 else dtheta_C - dtheta_w  (eq. 11)
ERROR clipped to [-M, M]                                                (eq. 12)
a <- a + ERROR / T_C                                                    (eq. 13)

only when (1) the turn exceeds 45 deg, (2) the speed stays within 15-45 mph while turning,
and (3) the compass is consistent (E_C below a bound throughout).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import safe_div, wrap
from .packed import packed_state
from .params import deg


class _RefineFields(NamedTuple):
    offset_before: jnp.ndarray   # smoothed H_C - H_W on the straight before a turn, rad
    offset_after_sum: jnp.ndarray  # distance-weighted sum of wrap(DELTA - offset_before) after the turn, rad.m
    offset_after_weight: jnp.ndarray  # distance with a valid compass in that sum, m
    straight_run: jnp.ndarray    # straight distance since the turn, m
    turn_active: jnp.ndarray     # 1.0 while a turn is being measured
    turn_angle: jnp.ndarray      # accumulated wheel heading change of the turn, rad
    gates_ok: jnp.ndarray        # 1.0 while gate (2) holds
    turn_samples: jnp.ndarray    # samples with a valid compass since the turn began
    turn_bad_samples: jnp.ndarray  # of which E_C exceeded refine_compass_max_error_deg
    updates: jnp.ndarray         # number of accepted refinements


RefineState = packed_state(
    _RefineFields, "RefineState",
    "The refinement's state as one float64 vector in _RefineFields order (jaxmodel/packed.py).")


def init_refine_state():
    z = jnp.zeros((), jnp.float64)
    return RefineState.pack(_RefineFields(z, z, z, z, z, z, jnp.ones((), jnp.float64), z, z, z))


def refine_step(params, rs, a, *, alpha, delta, d_t, speed, curvature, e_c, compass_ok, enabled):
    """One sample of the refinement.  Returns (new RefineState, new a).

    alpha: wheel heading change of this sample (rad); delta: wrapped H_C - H_W (rad);
    d_t: distance this sample (m); curvature: windowed dD/AD; e_c: compass bound (rad).
    ``enabled`` is static (Config.refine_a): off, state and a pass through untouched.
    """
    if not enabled:
        return rs, a
    rs = rs.fields()
    turning = jnp.abs(curvature) > params.turn_curvature
    compass_good = compass_ok & (e_c < deg(params.refine_compass_max_error_deg))
    speed_ok = (speed >= params.refine_speed_min) & (speed <= params.refine_speed_max)
    active = rs.turn_active > 0.5

    # Straight, no turn pending: follow the offset over refine_smoothing_m.
    gain = jnp.clip(d_t / params.refine_smoothing_m, 0.0, 1.0)
    follow = (~active) & (~turning) & compass_good  # gate (3) also before the turn
    offset_before = jnp.where(follow, wrap(rs.offset_before + gain * wrap(delta - rs.offset_before)), rs.offset_before)

    starts = (~active) & turning
    active_now = active | starts
    turn_angle = jnp.where(starts, alpha, jnp.where(active, rs.turn_angle + alpha, 0.0))
    gates_ok = jnp.where(starts, 1.0, rs.gates_ok)
    gate_fail = active_now & turning & ~speed_ok
    gates_ok = jnp.where(gate_fail, 0.0, gates_ok)
    # Gate (3), "consistent compass measurements": single samples above the bound are normal
    # (noise, body roll), so the turn passes when at most refine_compass_bad_fraction of its
    # compass samples exceed it.
    counted = active_now & compass_ok
    turn_samples = jnp.where(starts, 0.0, rs.turn_samples) + jnp.where(counted, 1.0, 0.0)
    turn_bad = jnp.where(starts, 0.0, rs.turn_bad_samples) + jnp.where(counted & ~compass_good, 1.0, 0.0)
    compass_consistent = turn_bad <= params.refine_compass_bad_fraction * turn_samples

    # After the turn: average the offset over the straight run; turning again restarts it.
    in_run = active_now & (~turning)
    run_weight = jnp.where(in_run & compass_ok, d_t, 0.0)
    straight_run = jnp.where(in_run, rs.straight_run + d_t, 0.0)
    after_sum = jnp.where(in_run, rs.offset_after_sum + run_weight * wrap(delta - offset_before), 0.0)
    # straight_run counts all distance; the mean uses only distance with a valid compass
    after_weight = jnp.where(in_run, rs.offset_after_weight + run_weight, 0.0)

    ends = active_now & (straight_run >= params.straight_distance_m)
    mean_shift = safe_div(after_sum, after_weight)  # off_after - off_before
    big_turn = jnp.abs(turn_angle) >= deg(params.refine_turn_min_deg)
    accept = ends & big_turn & (gates_ok > 0.5) & compass_consistent & (after_weight > 0.5 * straight_run)
    error = jnp.where(turn_angle >= 0.0, -mean_shift, mean_shift)  # eq. (11)
    error = jnp.clip(error, -deg(params.refine_M_deg), deg(params.refine_M_deg))  # eq. (12)
    a_new = jnp.where(accept, a + error / params.T_C, a)  # eq. (13)

    offset_before = jnp.where(ends, wrap(offset_before + mean_shift), offset_before)
    new = _RefineFields(
        offset_before=offset_before,
        offset_after_sum=jnp.where(ends, 0.0, after_sum),
        offset_after_weight=jnp.where(ends, 0.0, after_weight),
        straight_run=jnp.where(ends, 0.0, straight_run),
        turn_active=jnp.where(ends, 0.0, jnp.where(active_now, 1.0, 0.0)),
        turn_angle=jnp.where(ends, 0.0, turn_angle),
        gates_ok=jnp.where(ends, 1.0, gates_ok),
        turn_samples=jnp.where(ends, 0.0, turn_samples),
        turn_bad_samples=jnp.where(ends, 0.0, turn_bad),
        updates=rs.updates + jnp.where(accept, 1.0, 0.0),
    )
    return RefineState.pack(new), a_new
