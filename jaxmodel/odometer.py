"""The odometer stage of ``model.step`` (US 4,734,863 FIG. 8B): one sample's pulse counts decoded, judged and turned
into distances, speed, the windowed curvature and the wheel turn of eq. (8) with eq. (14)'s effective track.

``odometer`` returns the dict the rest of the step reads (``model.step``, ``drift_capture.calibrate``); the guard of
jaxmodel/plausibility.py judges the counts in the robust modes, the seed's max_speed check in the seed filter.
"""

from __future__ import annotations

import jax.numpy as jnp

from . import plausibility as _guard
from . import track as _track
from .angles import safe_div
from .packed import computed_once, value_once


INTERVAL_MIN_PULSES = 32.0
"""The wheel turn's interval (``odometer``) spans at least this many pulses of travel, beyond curvature_window_m.
The bias of dD_I / T_E(dD_I / AD_I) from the quantization of dD_I grows as (dpp / interval)^2 per metre; the 1-m
interval was chosen with 1.4-3-cm pulses (33-70 per interval).  With 7-cm pulses (an ABS ring of 29 teeth) the
odometer-only heading drifted 13.3 deg RMS on parking/baseline/101 (1.0 deg at 2.3 cm), 1.2 deg with 32 pulses
(stop 37, docs/tuning.md); the matrix's vehicles (dpp <= 3 cm) keep their 1-m interval.  The robust modes only:
the seed filter keeps the seed's."""

COUNTS_HOLD_MAX_S = 1.0
"""A logger faster than the wheel counters' own messages repeats their last counts: a sample whose counts did not
change within this long (s) of their last change says nothing new (the guard and the speed wait), and the next change
covers the whole time since the last one.  Longer, unchanged counts are a standstill.  Without it, counters updated
every 5th sample of a 10-Hz log put the default 17-41 deg RMS off and odometer-only 40-130 deg (stop 44: the guard
took each update for a burst at five times the speed)."""

HOLD_MIN_PULSES = 2.0
"""Unchanged counts are held only where the wheels' recent speed would have counted this many pulses in the sample."""


def decode_counter(count, last, modulus, expected=0.0):
    """Pulse increment of a counter that wraps at ``modulus``: the one within modulus/2 of ``expected`` (pulses; 0:
    in [-modulus/2, modulus/2]).  An unchanged count is no increment (a held counter, not a whole wrap)."""
    d = count - last
    return jnp.where(d == 0.0, 0.0, d - modulus * jnp.round((d - expected) / modulus))


def odometer(params, state, sample, track_table, robust=False):
    """Distances, speed, windowed curvature and the wheel heading change of one sample (FIG. 8B); with the
    guard (``robust``), also the wheels' time-smoothed turn rate (rad/s) and the turn's sigma (rad) where the guard
    substituted a wheel.  ``state``: model.State before the sample; ``sample``: model.Inputs (scalars)."""
    started = state.started > 0.5
    dt_raw = sample.time_s - state.last_time
    time_ok = jnp.isfinite(sample.time_s) & (dt_raw > 0.0) & started
    dt = jnp.where(time_ok, dt_raw, 0.0)
    counts = _decoded_counts(params, state, sample, started, time_ok, dt, robust)
    dpp = counts["dpp"]
    d_left, d_right, n_left, n_right, plausible, counted, kept, dD_sigma, guard_state = _plausible_distances(
        params, state, counts, started, time_ok, dt, robust)
    if robust:
        # The guard's distances and the sample's interval are read by most of the step: computed once.
        d_left, d_right, dt = value_once(d_left), value_once(d_right), value_once(dt)

    dD = d_left - d_right
    AD = 0.5 * (d_left + d_right)
    d_t = jnp.abs(AD)
    # (Robust modes: an interval so short that one pulse in it is beyond max_speed measures no speed, e.g. an FMU
    # master's 1-us step to an input event; its distance counts, the speed stays.)
    measured = time_ok & ~counts["held"]
    if robust:
        measured = measured & (dpp <= params.max_speed * counts["dt_counts"])
    speed = jnp.where(measured, safe_div(d_t, counts["dt_counts"]), state.speed)

    # The ``curvature`` output (and the refinement of a): dD/AD over an exponential window of curvature_window_m
    # travelled metres.
    signed_dD = jnp.where(AD >= 0.0, dD, -dD)
    keep = jnp.exp(-d_t / params.curvature_window_m)
    window_dD = keep * state.window_dD + signed_dD
    window_AD = keep * state.window_AD + d_t
    curvature = safe_div(window_dD, window_AD, eps=1e-6)
    track, alpha, interval = _interval_turn(params, state, dD, signed_dD, d_t, speed, dpp, track_table, robust)
    if robust:
        track, alpha, speed = value_once(track), value_once(alpha), value_once(speed)
    return dict(dt=dt, dt_counts=counts["dt_counts"], held=counts["held"], last_count_time=counts["last_count_time"],
                time_ok=time_ok, left=counts["left"], right=counts["right"], n_left=n_left, n_right=n_right, dD=dD,
                AD=AD, d_t=d_t, speed=speed, window_dD=window_dD, window_AD=window_AD, curvature=curvature,
                interval=interval, track=track, alpha=alpha, dpp=dpp, plausible=plausible, counted=counted, kept=kept,
                guard=guard_state, turn_rate=guard_state.rate_dD / track, turn_sigma=dD_sigma / track)


def _decoded_counts(params, state, sample, started, time_ok, dt, robust):
    """The sample's counts (non-finite ones replaced by the last), their increments (unwrapped at counter_modulus,
    around the wheels' recent speed in the robust modes), and the time they cover: held counters
    (COUNTS_HOLD_MAX_S) make dt_counts longer than dt and ``held`` the samples that repeat them."""
    counts_finite = jnp.isfinite(sample.left_pulses) & jnp.isfinite(sample.right_pulses)
    left = jnp.where(counts_finite, sample.left_pulses, state.last_left)
    right = jnp.where(counts_finite, sample.right_pulses, state.last_right)
    dpp_left, dpp_right = state.calibration.dpp_left, state.calibration.dpp_right
    g = state.guard.fields()  # the wheels' recent speeds (robust modes)
    expected_left = expected_right = 0.0
    if robust:
        # Robust modes decode around the increment the wheels' recent speed predicts (the guard's rates): a counter
        # that turns by more than half its modulus between two samples is still unwrapped (a 12-bit counter on a
        # 2-cm pulse at 20 m/s logged at 0.5 Hz; an 8-bit one logged at 1 Hz above 2.5 m/s).
        recent = time_ok & (dt <= _guard.GUARD_HORIZON_S)
        expected_left = jnp.where(recent, g.rate_left * dt / dpp_left, 0.0)
        expected_right = jnp.where(recent, g.rate_right * dt / dpp_right, 0.0)
    n_left = decode_counter(left, state.last_left, params.counter_modulus, expected_left)
    n_right = decode_counter(right, state.last_right, params.counter_modulus, expected_right)
    dpp = jnp.maximum(dpp_left, dpp_right)  # the longer pulse: the counts' resolution
    # Held counters (COUNTS_HOLD_MAX_S, robust modes): the interval a change of the counts covers, and the samples
    # that repeat them.  The seed filter keeps the seed's per-sample interval.
    changed = counts_finite & ((n_left != 0.0) | (n_right != 0.0))
    since = sample.time_s - state.last_count_time
    dt_counts, held, motion_dt = dt, jnp.zeros_like(changed), dt
    if robust:
        dt_counts = jnp.where(time_ok, jnp.clip(since, dt, jnp.maximum(dt, COUNTS_HOLD_MAX_S)), 0.0)
        # Only where the wheels' recent speed would have counted HOLD_MIN_PULSES in the sample: fewer unchanged
        # counts are a slow wheel's quantization.
        expected = jnp.maximum(jnp.abs(g.rate_left), jnp.abs(g.rate_right)) * dt / dpp
        held = time_ok & counts_finite & ~changed & (since < COUNTS_HOLD_MAX_S) & (expected >= HOLD_MIN_PULSES)
        # Unchanged for longer than twice the hold, the car stood: the change came within this sample.
        motion_dt = jnp.where(since > 2.0 * COUNTS_HOLD_MAX_S, dt, dt_counts)
    last_count_time = jnp.where(jnp.isfinite(sample.time_s) & (~started | (changed & time_ok)), sample.time_s,
                                state.last_count_time)
    return dict(counts_finite=counts_finite, left=left, right=right, n_left=n_left, n_right=n_right, dpp=dpp,
                dt_counts=dt_counts, held=held, motion_dt=motion_dt, last_count_time=last_count_time)


def _plausible_distances(params, state, counts, started, time_ok, dt, robust):
    """The wheels' distances (m) and pulse increments after the plausibility checks (speed and course,
    jaxmodel/plausibility.py; the seed filter: max_speed alone).  Returns (d_left, d_right, n_left, n_right,
    plausible: no counter fault, counted: the increments are the counts as they were (plausible, and nothing
    substituted or removed, nor a removal corrected by the vernier), kept: the sample's motion used, dD_sigma (m):
    the uncertainty of a substituted wheel, the guard's state)."""
    dpp_left, dpp_right = state.calibration.dpp_left, state.calibration.dpp_right
    n_left, n_right, counts_finite = counts["n_left"], counts["n_right"], counts["counts_finite"]
    if robust:
        # A glitched sample keeps the vehicle's motion, substituted from the other wheel and the recent turn rate.
        d_left, d_right, raw_ok, speed_ok, kept, dD_sigma, guard_state = _guard.guard(
            params, state.guard, n_left * dpp_left, n_right * dpp_right, counts["dt_counts"], time_ok,
            counts_finite & started, dpp_left, dpp_right, counts["held"], counts["motion_dt"])
        n_left = jnp.where(raw_ok, n_left, d_left / dpp_left)
        n_right = jnp.where(raw_ok, n_right, d_right / dpp_right)
        # odometer_valid reports counter faults (a wheel beyond max_speed, non-finite counts), as
        # without the guard; a burst within max_speed is substituted (its motion kept) and not a fault.
        # (A wheel that stopped counting is substituted too; estimate warns of it from the log itself.)
        return d_left, d_right, n_left, n_right, speed_ok, raw_ok, kept, dD_sigma, guard_state
    # A jump beyond max_speed (over the sample interval, 0.1 s if the time step is unusable)
    # is a counter fault; the sample's distance is dropped and the counters resync.
    d_left, d_right = n_left * dpp_left, n_right * dpp_right
    limit = params.max_speed * jnp.where(time_ok, dt, 0.1) + 2.0 * counts["dpp"]
    plausible = counts_finite & started & (jnp.abs(d_left) <= limit) & (jnp.abs(d_right) <= limit)
    d_left = jnp.where(plausible, d_left, 0.0)
    d_right = jnp.where(plausible, d_right, 0.0)
    n_left = jnp.where(plausible, n_left, 0.0)
    n_right = jnp.where(plausible, n_right, 0.0)
    return d_left, d_right, n_left, n_right, plausible, plausible, plausible, jnp.zeros_like(d_left), state.guard


def _interval_turn(params, state, dD, signed_dD, d_t, speed, dpp, track_table, robust):
    """The wheel turn alpha (rad) of this sample, eq. (8) with eq. (14)'s T_E per interval of travel, the track it
    used (m) and the interval's sums for the next sample (zeroed where the interval ended)."""
    # The wheel turn, eq. (8) with eq. (14)'s T_E, evaluated per interval of curvature_window_m travelled metres
    # from the interval's own dD/AD, as the seed evaluates once per interval (once per second): per sample at
    # 10 Hz dD/AD is mostly pulse quantization, and pairing each sample's dD with a window that contains its own
    # quantization over-turns in tight turns by a bias per *sample* (T_E is steep near c_max), while a window
    # without it lags the turn (under-turns); at 10 Hz on the matrix's vehicles the two happened to cancel, but a
    # parking drive's wheel heading drifted 14 deg RMS logged at 50 Hz, 8-23 deg with 4-cm pulses (docs/tuning.md,
    # stop 35).
    # The interval's turn is re-evaluated every sample (``alpha`` is its change), so H_W follows within the
    # interval and its sum over the interval is dD_I / T_E(dD_I / AD_I).
    interval_dD = state.interval_dD + _track.velocity_corrected(dD, state.a, speed)
    interval_signed_dD = state.interval_signed_dD + signed_dD
    interval_AD = state.interval_AD + d_t
    interval_curvature = safe_div(interval_signed_dD, interval_AD, eps=1e-9)
    if track_table is None:
        t_front = _track.effective_track(interval_curvature, params.P, params.B, params.T_F, params.curvature_clip)
    else:
        t_front = _track.effective_track_lookup(interval_curvature, track_table)
    track = jnp.where(params.sensor_axle > 0.5, t_front, params.T_R)
    turn = interval_dD / track
    alpha = turn - state.interval_turn
    # Coarse pulses (robust): the interval holds at least INTERVAL_MIN_PULSES pulses of travel.
    interval_m = params.curvature_window_m
    if robust:
        interval_m = jnp.maximum(interval_m, INTERVAL_MIN_PULSES * dpp)
    ended = computed_once(interval_AD >= interval_m)
    interval = dict(interval_dD=interval_dD, interval_signed_dD=interval_signed_dD, interval_AD=interval_AD,
                    interval_turn=turn)
    return track, alpha, {k: jnp.where(ended, 0.0, v) for k, v in interval.items()}
