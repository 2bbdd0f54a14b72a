"""Plausibility of the wheel pulse counts in every mode (US 4,680,715's speed and course checks).

US 4,680,715 rejects a speed change beyond what the vehicle can do and a course change beyond
its yaw rate.  Here the same two checks guard the odometer itself, before any mode sees it, and
a rejected sample keeps the vehicle's real motion instead of dropping it:

* speed: each wheel's increment must be within ``max_speed`` over the sample interval (a
  counter fault, a wrong ``counter_modulus`` wrap, a +-3000-count spike);
* course: the differential increment dD must agree with its recent rate (time-smoothed over
  ``GUARD_TAU_S``) within ``glitch_pulses`` pulses plus ``glitch_dD_rate`` x dt (x dt / COURSE_REFERENCE_DT_S
  beyond that interval: ``course_tolerance``): dD is the turn, and a car's yaw rate cannot jump within one
  sample, while a burst of spurious pulses on one wheel moves dD by the whole burst;
* geometry (front-axle sensors): a dD beyond IMPOSSIBLE_CURVATURE_FACTOR times eq. (14)'s geometric maximum
  of dD/AD, per sample or over GUARD_WINDOW_M of the raw counts, is no vehicle's turn (a sensor that stopped
  counting: dD/AD = 2); on either axle, a wheel that reads nothing while turning about it would be a lateral
  acceleration beyond MAX_LATERAL_ACCEL.  Such samples are replaced by the other wheel's travel with no turn for
  as long as they last, and ``dD_sigma`` hands the filter that turn's uncertainty.  One sample on which a wheel
  counts beyond its own recent rate while both count is a burst however large (removed as below), not a wheel that
  stopped counting; from the second such sample in a row it is impossible again (a chattering sensor).

Which wheel is at fault: the one whose increment departs more from its own recent rate.  The
whole number of pulses by which it departs from the other wheel's increment plus (or minus) the
predicted dD is removed from it, so AD and the turn of that sample stay what the vehicle did and
the wheel keeps its own count.  That whole number is exact when it is a counter modulus of
``COMMON_MODULI`` (a counter that wraps at another modulus than ``counter_modulus`` says) or
undoes the pulses last removed from that wheel (a spike that returns), within
``SNAP_PULSES``; otherwise the rounding can miss by one pulse, and jaxmodel/vernier.py estimates the
removal again from both sides of it (the narrowest band of the cumulative dD before and after) and takes
off the pulse it missed, ``VERNIER_SAMPLES`` samples later.  When both wheels fail (or after
``GUARD_MAX_SUBSTITUTED`` substitutions in a row) both are replaced by their predictions for
that sample.  The counter references always follow the counters (resync), so a burst that
permanently offsets one counter costs nothing after its sample, and a spike costs nothing
after the sample that returns.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from . import vernier as _vernier
from .packed import computed_once, packed_state
from .track import max_curvature

GUARD_TAU_S = 0.3
"""Time constant (s) of the wheel and dD rates the next increments are predicted from."""
GUARD_MAX_SUBSTITUTED = 20.0
"""After this many substituted samples in a row the counts are believed again (a real jump)."""
GUARD_WINDOW_M = 0.2
"""Travelled metres of the raw counts' curvature window behind ``impossible`` (short: a stuck wheel turns the wheel
heading by 2/T rad per metre until it is seen; ~7 deg for the matrix's vehicles)."""
IMPOSSIBLE_CURVATURE_FACTOR = 2.0
"""With front-axle sensors, a sample whose |dD| exceeds this times eq. (14)'s geometric maximum of dD/AD times |AD|
(plus the counts' quantization: 3 pulses per sample, 4 over GUARD_WINDOW_M) is substituted however many came
before it: the runs beyond GUARD_MAX_SUBSTITUTED that are believed again are real changes of turn, never a wheel
that stopped counting (stop 31: a left sensor stuck for 5 s put the default 8-28 deg RMSE off on every baseline
drive of the outside bench).  The factor leaves room for nominal B and T_F; rear-axle sensors have no such bound
(a skid-steer robot pivots)."""
MAX_LATERAL_ACCEL = 12.0
"""m/s^2: the sensor axle's lateral acceleration v omega that no tyre on a road exceeds (about 1.2 g).  A wheel
that reads nothing while the other moves is ``impossible`` on either axle when turning about the still wheel would be
beyond it (within 3 pulses of dD): a wheel that stopped counting is seen from a wheel speed of sqrt(2
MAX_LATERAL_ACCEL T), ~6 m/s (below that, on the rear axle, it cannot be told from a skid-steer's tight turn); a
pivot (v ~ 0) never reaches it.  The matrix's drives stay below 2.4 m/s^2."""
GUARD_HORIZON_S = 10.0
"""Rates learned before a gap in time longer than this (s) predict nothing: across it the course check is
off and no motion is substituted (a logger that stopped for minutes, a clock that jumped; extrapolated
over 1e300 s, the recent turn rate put the wheel heading 1e282 rad off)."""
STOPPED_MIN_S = 1.0
"""A counter that did not change for this long (s) while the other counted on is reported as a wheel sensor fault
(``estimate``'s warnings, the FMUs' logs); the guard substitutes such samples where it can tell them from a turn."""
STOPPED_OTHER_PULSES = 3.0
"""... while the other counted at least this many pulses per sample (beyond the quantization of a slow inner wheel)."""
COMMON_MODULI = (256.0, 1000.0, 1024.0, 4096.0, 10000.0, 16384.0, 32768.0, 65536.0, 100000.0)
"""Counter moduli of wheel-pulse counters (8-16 bit, decimal): a jump by one of them is a wrap."""
_SIGNED_MODULI = tuple(m * sign for m in COMMON_MODULI for sign in (1.0, -1.0))
SNAP_PULSES = 3.0
"""A removal within this many pulses of a modulus or of a returning spike is taken as exactly that."""


COURSE_REFERENCE_DT_S = 0.1
"""The sample interval (s, 10 Hz) at which ``glitch_dD_rate`` is the dD rate's change allowed within one sample; over
longer intervals the allowed change grows with the interval (``course_tolerance``)."""


def course_tolerance(params, dpp, step_dt):
    """How far (m) one sample's dD may depart from its recent rate times the interval ``step_dt`` (s): glitch_pulses
    pulses of quantization plus glitch_dD_rate x step_dt, and beyond COURSE_REFERENCE_DT_S times step_dt /
    COURSE_REFERENCE_DT_S more.

    A yaw acceleration changes the yaw rate in proportion to the time, and dD by the rate times the time: the
    departure grows as step_dt^2.  glitch_dD_rate (0.5 m/s of dD rate, 18 deg/s of yaw rate on a 1.6-m track, within
    0.1 s) was set at 10 Hz, where it is a yaw acceleration of ~185 deg/s^2.  Read as a fixed change per sample, at
    1 Hz it allowed 18 deg/s within a second, and a car entering a street corner turns faster than that: the turn
    was substituted by the recent (straight) rate and the wheel heading lost it (independent simulator logged at
    1 Hz: odometer mode 92 deg RMSE, the default 23 deg; docs/tuning.md, stop 51).  At 10 Hz and faster the
    tolerance is unchanged.  A burst of spurious pulses smaller than the tolerance then passes as a turn: at 1 Hz the
    counts cannot tell 30 pulses of burst from a second of cornering."""
    stretch = jnp.maximum(step_dt / COURSE_REFERENCE_DT_S, 1.0)
    return params.glitch_pulses * dpp + params.glitch_dD_rate * step_dt * stretch


_GUARD_FIELDS = (
    "rate_left",    # m/s, time-smoothed left wheel speed (signed)
    "rate_right",   # m/s
    "rate_dD",      # m/s, time-smoothed dD rate
    "substituted",  # substituted samples in a row
    "removed_left",   # pulses last removed from the left counter (0: none pending)
    "removed_right",  # pulses last removed from the right counter
    # The raw counts' dD (signed as the travel) and |AD| over an exponential window of GUARD_WINDOW_M travelled
    # metres (m, m): a curvature no front axle can drive (``impossible``).
    "window_dD",
    "window_AD",
)
GuardFields = NamedTuple("GuardFields", [(name, jnp.ndarray) for name in _GUARD_FIELDS + _vernier.FIELDS])
"""The guard's fields, then the two-sided re-estimate's (jaxmodel/vernier.py ``FIELDS``)."""
_VERNIER = GuardFields._fields.index(_vernier.FIELDS[0])


GuardState = packed_state(GuardFields, "GuardState", "State of the odometer plausibility guard (one float64 vector).")


def init_guard_state():
    z = jnp.zeros((), jnp.float64)
    return GuardState.pack(GuardFields(*([z] * len(GuardFields._fields))))


def _snap(pulses, removed):
    """The whole number of spurious pulses: a common modulus (either sign) or -removed (a spike
    returning) when within SNAP_PULSES of ``pulses`` (the nearest), else ``pulses`` rounded; and whether
    it was such an exact candidate (bool)."""
    # One small vector of candidates, reduced with min and max (no argmin: the native FMU's lowering,
    # fmu/jaxpr_lower.py, has none); a chain of scalar selections cost 2x the robust step's time.
    candidates = jnp.concatenate([jnp.asarray(_SIGNED_MODULI), jnp.where(removed != 0.0, -removed, jnp.inf)[None]])
    miss = jnp.abs(pulses - candidates)
    best_miss = jnp.min(miss)
    nearest = jnp.max(jnp.where(miss == best_miss, candidates, -jnp.inf))
    return jnp.where(best_miss <= SNAP_PULSES, nearest, jnp.round(pulses)), best_miss <= SNAP_PULSES


class _Checks(NamedTuple):
    """One sample's increments against the guard's rates (``_checks``)."""
    pred_left: jnp.ndarray   # m, each wheel's increment predicted from its rate
    pred_right: jnp.ndarray
    pred_dD: jnp.ndarray     # m, dD predicted from its rate
    left_fast: jnp.ndarray   # the wheel's increment is beyond max_speed
    right_fast: jnp.ndarray
    left_departs: jnp.ndarray  # the left increment departs from its rate at least as far as the right one
    dD: jnp.ndarray          # m, the raw dD
    turn_bad: jnp.ndarray    # dD departs from its prediction beyond ``course_tolerance``
    speed_ok: jnp.ndarray    # counts_ok and neither wheel beyond max_speed


class _Substitution(NamedTuple):
    """The sample after the guard's decision (``_substitution``), before the vernier."""
    d_left: jnp.ndarray   # m, the increments kept (raw, substituted or 0)
    d_right: jnp.ndarray
    raw_ok: jnp.ndarray   # the counts passed every check as they were
    fix: jnp.ndarray      # the sample's motion was substituted
    kept: jnp.ndarray     # the sample's motion is used
    single: jnp.ndarray   # pulses were removed from one wheel
    start: jnp.ndarray    # that removal was rounded (jaxmodel/vernier.py estimates it again)
    cancel: jnp.ndarray   # a returning spike or a stuck wheel's substitution: the pending estimate is void
    blame_left: jnp.ndarray  # the wheel at fault is the left one
    pulses_left: jnp.ndarray
    pulses_right: jnp.ndarray


def guard(params, gs, d_left, d_right, dt, time_ok, counts_ok, dpp_left, dpp_right, held=False, motion_dt=None):
    """Check one sample's wheel increments (m) with US 4,680,715's speed and course checks; returns (d_left, d_right,
    raw_ok, speed_ok, kept, dD_sigma, new GuardState).

    dpp_left, dpp_right: metres per pulse of each wheel (the increments are whole multiples of them).

    raw_ok: the counts passed both checks as they were; speed_ok: they passed the speed check (a
    wheel beyond max_speed is a counter fault, not motion: the FMUs discard such a sample); kept: the
    sample's motion is used (raw or substituted); dD_sigma: the uncertainty (m of dD) of a turn
    substituted for an ``impossible`` sample, else 0.  ``counts_ok`` is False for non-finite counts and
    the first sample (no motion).  dt: the time the increments cover (s; since the counts last changed, see
    ``odometer.COUNTS_HOLD_MAX_S``); ``held``: the counts repeat the last ones within that hold (no news: nothing is
    checked and the rates wait for the change that covers the hold).  ``motion_dt`` (s; default dt): the time the
    wheels can have moved in, for the course check's change of turn rate and the lateral acceleration of a turn
    about a still wheel: the sample's own interval after a standstill, when dt (the time since the counts changed, up
    to the hold) is longer than the car moved.
    """
    g = gs.fields()
    dpp = jnp.maximum(dpp_left, dpp_right)
    step_dt = jnp.where(time_ok, dt, 0.1)
    # After a standstill the wheels moved within the sample, not over the hold: 25 pulses on one wheel passed as a
    # pivot turn of 18-42 deg (docs/tuning.md, stop 52).
    moved_dt = step_dt if motion_dt is None else jnp.where(time_ok, jnp.minimum(motion_dt, step_dt), step_dt)
    c = _checks(params, g, d_left, d_right, step_dt, moved_dt, counts_ok, dpp, held)
    c_max = max_curvature(params.B, params.T_F)
    track = jnp.where(params.sensor_axle > 0.5, params.T_F, params.T_R)
    window, impossible, dead_left, one_dead = _impossible(params, g, d_left, d_right, c, dpp, moved_dt, c_max, track)
    s = _substitution(g, d_left, d_right, c, impossible, dead_left, one_dead, counts_ok, dpp_left, dpp_right)
    usable = time_ok & s.kept & ~held  # the samples the rates, the vernier and the window learn from
    d_left, d_right, v, fired = _vernier.vernier(gs.vector[..., _VERNIER:], s.d_left, s.d_right, usable, s.start,
                                                 s.cancel, jnp.where(s.blame_left, 1.0, -1.0), dpp_left, dpp_right)
    new = _next_guard_state(g, s, c.turn_bad, window, d_left, d_right, step_dt, time_ok, usable, v)
    dD_sigma = _substituted_sigma(d_left, d_right, s.fix, impossible, c_max, track, step_dt)
    return d_left, d_right, s.raw_ok & ~fired, c.speed_ok, s.kept, dD_sigma, new


def _checks(params, g, d_left, d_right, step_dt, moved_dt, counts_ok, dpp, held):
    """US 4,680,715's speed check (each wheel within max_speed) and course check (dD within ``course_tolerance``
    of its recent rate) of one sample's increments, and the increments the rates predict."""
    pred_left, pred_right = g.rate_left * step_dt, g.rate_right * step_dt
    pred_dD = g.rate_dD * step_dt
    speed_limit = params.max_speed * step_dt + 2.0 * dpp
    left_fast = jnp.abs(d_left) > speed_limit
    right_fast = jnp.abs(d_right) > speed_limit
    dD = d_left - d_right
    tol = course_tolerance(params, dpp, moved_dt)
    turn_bad = (jnp.abs(dD - pred_dD) > tol) & (step_dt <= GUARD_HORIZON_S) & ~held
    speed_ok = counts_ok & ~left_fast & ~right_fast
    left_departs = jnp.abs(d_left - pred_left) >= jnp.abs(d_right - pred_right)
    return _Checks(pred_left, pred_right, pred_dD, left_fast, right_fast, left_departs, dD, turn_bad, speed_ok)


def _impossible(params, g, d_left, d_right, c, dpp, moved_dt, c_max, track):
    """Whether the sample is no vehicle's motion: a front-axle turn beyond IMPOSSIBLE_CURVATURE_FACTOR times eq.
    (14)'s geometric maximum c_max, or a still wheel beyond MAX_LATERAL_ACCEL on either axle (``track``: the sensor
    axle's).  Returns (the raw counts' curvature window, impossible, dead_left, one_dead)."""
    # A front-axle turn beyond IMPOSSIBLE_CURVATURE_FACTOR times eq. (14)'s geometric maximum curvature is no
    # vehicle's motion however long it lasts (a wheel sensor that stopped counting: dD/AD = 2).  Per sample each
    # wheel's count is within a pulse of its travel (dD within 2 pulses, AD within 1); over the last GUARD_WINDOW_M
    # of the raw counts, whose cumulative counts keep that bound, a slow stuck wheel is seen too.
    window_dD, window_AD = _curvature_window(g, d_left, d_right, c.speed_ok)
    c_impossible = IMPOSSIBLE_CURVATURE_FACTOR * c_max
    # On either axle, a wheel that reads nothing while the other moves so fast that turning about the still wheel
    # would be a lateral acceleration v omega = |AD dD| / (T dt^2) beyond MAX_LATERAL_ACCEL has stopped counting.
    # (Only a dead wheel: a simulator's turn may well be beyond what tyres can do, a burst never reads zero.)
    ad = jnp.abs(0.5 * (d_left + d_right))
    dead_left = (d_left == 0.0) & (d_right != 0.0)
    one_dead = dead_left | ((d_right == 0.0) & (d_left != 0.0))
    dead_at_speed = one_dead & ((jnp.abs(c.dD) - 3.0 * dpp) * ad > MAX_LATERAL_ACCEL * track * moved_dt * moved_dt)
    # A wheel that counts more than its own recent rate, where it departs from its rate more than the other (the wheel
    # at fault), while both count, after a sample that was not substituted, is a burst of spurious pulses however
    # large: removed as a burst (the vernier estimates it again), not replaced as a wheel that stopped counting, whose
    # turn is a guess of up to c_max |AD| (dD_sigma).  At 4 m/s 29 pulses of 2 cm passed for a stuck wheel: a pulse
    # off and no vernier, and the default mode, told the turn was unknown to 3.4 deg, followed a compass 3 deg off
    # (independent simulator, mixed s60; docs/tuning.md, stop 89).  A wheel that over-counts sample after sample (a
    # chattering sensor) stays impossible from its second sample on: substituted however long it lasts.
    over_counts = jnp.where(c.left_departs, jnp.abs(d_left) > jnp.abs(c.pred_left),
                            jnp.abs(d_right) > jnp.abs(c.pred_right))
    burst = ~one_dead & over_counts & (g.substituted < 0.5)
    impossible = computed_once(c.speed_ok & ~burst & (dead_at_speed | ((params.sensor_axle > 0.5) & (
        (jnp.abs(window_dD) > c_impossible * window_AD + 4.0 * dpp)
        | (jnp.abs(c.dD) > c_impossible * ad + 3.0 * dpp)))))
    return (window_dD, window_AD), impossible, dead_left, one_dead


def _substitution(g, d_left, d_right, c, impossible, dead_left, one_dead, counts_ok, dpp_left, dpp_right):
    """The guard's decision on a sample that failed a check: its motion substituted (the wheel at fault less a
    whole number of spurious pulses, or both wheels' predictions), believed again after GUARD_MAX_SUBSTITUTED in a
    row, or dropped (US 4,680,715's rejection, here keeping the vehicle's motion)."""
    trusting = (g.substituted < GUARD_MAX_SUBSTITUTED) | impossible
    raw_ok = c.speed_ok & ~c.turn_bad & ~impossible
    blame_left = _blame_left(c, d_left, d_right, impossible, dead_left, one_dead)
    both = computed_once(c.left_fast & c.right_fast)
    # Flags read by every field of the state: computed once (packed.computed_once).
    fix = computed_once(counts_ok & ~raw_ok & trusting)
    new_left, new_right = _predicted_motion(c, d_left, d_right, impossible, blame_left, both)
    exact, returning, pulses_left, pulses_right = _spurious_pulses(g, d_left, d_right, new_left, new_right,
                                                                   blame_left, dpp_left, dpp_right)
    spurious_left, spurious_right = pulses_left * dpp_left, pulses_right * dpp_right
    new_left = jnp.where(both, new_left, d_left - spurious_left)
    new_right = jnp.where(both, new_right, d_right - spurious_right)
    d_left = jnp.where(fix, new_left, d_left)
    d_right = jnp.where(fix, new_right, d_right)
    # A run of failures beyond GUARD_MAX_SUBSTITUTED: believe the wheels again unless a wheel is
    # beyond max_speed (that sample is dropped), so a true change of turn is not fought forever.
    believe = counts_ok & ~raw_ok & ~trusting
    drop = believe & (c.left_fast | c.right_fast)
    d_left = jnp.where(drop | ~counts_ok, 0.0, d_left)
    d_right = jnp.where(drop | ~counts_ok, 0.0, d_right)
    kept = computed_once(counts_ok & ~drop)
    # A rounded removal (not an exact modulus or returning spike) is estimated again, two-sided, once
    # vernier.VERNIER_SAMPLES samples from it on have been seen; the pulse it missed is taken off then.
    single = fix & ~both
    # A stuck wheel's run has no step to re-estimate from both sides: no vernier (a pending one is dropped).  A
    # spike's return voids the estimate its first sample began; a modulus removed leaves its dD right.
    start = computed_once(single & ~exact & ~impossible)
    cancel = single & (impossible | returning)
    return _Substitution(d_left, d_right, raw_ok, fix, kept, single, start, cancel, blame_left, pulses_left,
                         pulses_right)


def _blame_left(c, d_left, d_right, impossible, dead_left, one_dead):
    """Whether the wheel at fault is the left one: the one beyond max_speed, else the one whose increment departs
    more from its own recent rate, or the one reading nothing in an impossible turn."""
    blame_left = c.left_fast | (~c.right_fast & c.left_departs)
    # An impossible turn with one wheel reading nothing: that wheel stopped counting (the other may well be
    # accelerating away from its rate).
    return jnp.where(impossible & one_dead, dead_left, blame_left)


def _predicted_motion(c, d_left, d_right, impossible, blame_left, both):
    """The increments (m) that replace a failed sample's: both wheels' predictions when both failed, else the wheel
    at fault follows the other by the predicted dD (no turn for an impossible sample)."""
    # A wheel that stopped counting says nothing of the turn, and the guard's turn rate may have learned the samples
    # of it that passed (at parking speeds): it is replaced by the other wheel's travel (no turn), and the filter
    # is told the turn is unknown (``dD_sigma``).
    pred_dD = jnp.where(impossible, 0.0, c.pred_dD)
    new_left = jnp.where(both, c.pred_left, jnp.where(blame_left, d_right + pred_dD, d_left))
    new_right = jnp.where(both, c.pred_right, jnp.where(blame_left, d_right, d_left - pred_dD))
    return new_left, new_right


def _spurious_pulses(g, d_left, d_right, new_left, new_right, blame_left, dpp_left, dpp_right):
    """The whole number of spurious pulses to remove from the wheel at fault (``_snap``).  Returns (exact, returning,
    pulses_left, pulses_right): whether it was a modulus or a returning spike, whether it undid the pulses last
    removed from that wheel (a spike returning), and the pulses removed from each wheel (0 from the other)."""
    # Remove a whole number of spurious pulses from the wheel at fault, so its own count (and its
    # quantization phase) is kept; a miss by one pulse is what remains of a glitch.
    # Only the wheel at fault has pulses removed: one snap, on its count.
    removed = jnp.where(blame_left, g.removed_left, g.removed_right)
    pulses, exact = _snap(jnp.where(blame_left, (d_left - new_left) / dpp_left, (d_right - new_right) / dpp_right),
                          removed)
    pulses_left, pulses_right = jnp.where(blame_left, pulses, 0.0), jnp.where(blame_left, 0.0, pulses)
    return exact, exact & (removed != 0.0) & (pulses == -removed), pulses_left, pulses_right


def _next_guard_state(g, s, turn_bad, window, d_left, d_right, step_dt, time_ok, usable, v):
    """The GuardState after the sample: the rates moved towards the kept increments (time constant GUARD_TAU_S),
    the substitutions in a row, the pending removals, the curvature window and the vernier's fields ``v``."""
    w = jnp.where(usable, 1.0 - jnp.exp(-step_dt / GUARD_TAU_S), 0.0)
    inv_dt = jnp.where(time_ok, 1.0 / step_dt, 0.0)
    substituted = jnp.where(s.fix, g.substituted + 1.0, 0.0)
    base = jnp.stack([g.rate_left + w * (d_left * inv_dt - g.rate_left),
                      g.rate_right + w * (d_right * inv_dt - g.rate_right),
                      g.rate_dD + w * ((d_left - d_right) * inv_dt - g.rate_dD),
                      substituted,
                      _pending(s.single, s.pulses_left, g.removed_left),
                      _pending(s.single, s.pulses_right, g.removed_right),
                      *_stored_window(g, turn_bad, window, d_left, d_right, usable)],
                     axis=-1)
    return GuardState(jnp.concatenate([base, v], axis=-1))


def _substituted_sigma(d_left, d_right, fix, impossible, c_max, track, step_dt):
    """dD_sigma: the uncertainty (m of dD) of the turn substituted for an impossible sample, else 0."""
    lateral_limit = MAX_LATERAL_ACCEL * track * step_dt * step_dt  # the largest |AD dD| (m^2) of a sample
    # The turn substituted for an impossible sample is a guess within c_max of the travel (and within the lateral
    # acceleration bound): its uncertainty (m of dD).
    ad_kept = jnp.abs(0.5 * (d_left + d_right))
    return jnp.where(fix & impossible, jnp.minimum(c_max * ad_kept, lateral_limit / jnp.maximum(ad_kept, 1e-3)), 0.0)


def _curvature_window(g, d_left, d_right, usable):
    """The exponential window of GUARD_WINDOW_M travelled metres moved on by one sample's increments (m):
    (dD signed as the travel, |AD|); unchanged where not ``usable``."""
    ad = 0.5 * (d_left + d_right)
    keep = jnp.exp(-jnp.abs(ad) / GUARD_WINDOW_M)
    dD = d_left - d_right
    return (jnp.where(usable, keep * g.window_dD + jnp.where(ad >= 0.0, dD, -dD), g.window_dD),
            jnp.where(usable, keep * g.window_AD + jnp.abs(ad), g.window_AD))


def _stored_window(g, turn_bad, raw_window, d_left, d_right, usable):
    """The curvature window kept for the next sample: the raw counts', except after a sample the course check
    failed (a burst or a spike: its substitute is kept, so one burst does not make the next metres look
    impossible); a stuck wheel passes the course check at low speed and, at speed, is judged on each sample."""
    final = _curvature_window(g, d_left, d_right, usable)
    return jnp.where(turn_bad, final[0], raw_window[0]), jnp.where(turn_bad, final[1], raw_window[1])


def _pending(fixed, pulses, removed):
    """Pulses last removed from a counter: this sample's when it removed some (0 when it undid the
    previous removal exactly: nothing pending any more), else unchanged."""
    undone = pulses == -removed
    return jnp.where(fixed & (pulses != 0.0), jnp.where(undone, 0.0, pulses), removed)
