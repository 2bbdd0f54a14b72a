"""The wheels' drift confirmed: the left/right calibration (EP 0619873) run with the robust F-DELTA's rate filter.

``calibrate`` runs the seed's calibration (``calibration.calibration_step``), then, in the robust complementary and
Kalman modes (``f_delta.captures_drift``), confirms a drift of the wheel heading that the rate filter measures:

* a large, significant drift (``rate_significance.large_drift``, beyond CAPTURE_RATE_Z sigmas) is a tyre mismatch and is
  captured into the ratio at once (``calibration.capture_rate``);
* a smaller one that the stretches corroborate (``corroborated``) restarts the steady filter's follow hold, so the
  heading follows the rate filter while the stretches refine the ratio;
* a ratio that moved by more than RECALIBRATION_HOLD within filter_follow_hold_m of a large drift restarts it too.

Each completed stretch also measures the rate filter's rate (``measure_rate``): the drift the ratio in force leaves,
seen in the pulse counts alone, so that the rate filter does not take a compass error for it (docs/tuning.md, stop 54).

A new ratio changes the wheel heading's rate per metre; the rate filter's rate follows at once
(``offset_filter.shift_rate``).
"""

from __future__ import annotations

import jax.numpy as jnp

from . import calibration as _cal
from . import f_delta as _fdelta
from . import offset_filter as _offset
from . import rate_significance as _rate
from .angles import safe_div as _safe_div
from .packed import computed_once

RECALIBRATION_HOLD = 1e-4
"""Relative change of the ratio in one calibration update beyond which the steady F-DELTA's follow hold restarts."""

CORROBORATED_RATE_Z = 4.0
"""The rate filter's rate is corroborated only beyond this many of its sigmas (filter_rate_significance is 2.9; the
dip errors of highway/hills/105 faked 50-110 µrad/m at 3-4.7 sigmas for 10 km, which the stretches did not share)."""
CORROBORATED_STRETCH_Z = 1.5
"""... by stretches whose filtered ratio is beyond this many of its sigmas from the applied ratio
(``stretches_rate``),"""
CORROBORATED_FACTOR = 2.0
"""... in the same direction, the two rates within this factor of each other."""


def _beyond(rate_filter, z):
    """Whether the rate filter's rate is beyond ``z`` of its sigmas (bool)."""
    return rate_filter.beta ** 2 > z ** 2 * rate_filter.p11


def corroborated(params, cs, rate_filter, track):
    """Whether the stretches corroborate the rate filter's drift (bool): the two measure a tyre mismatch independently
    (the stretches the pulse counts on straight roads, the rate filter the compass against the wheels), and a drift
    both see, in the same direction and of about the same size, is the wheels'.

    Where the seed is silent.  A mismatch of 0.01-0.08 % drifts the wheels by 60-500 µrad/m: under the large drift
    (filter_follow_hold_rate) and the show rate's smooth step, and under the stretches' significance for 20 km
    (independent simulator, highway seed 61, 0.017 % hidden: the rate filter 70-90 µrad/m at 4-6 sigmas, the stretches'
    unapplied mean 90-160 µrad/m at 1.3-2.8 sigmas; the steady filter lagged 17 deg; docs/tuning.md, stop 53).  Each
    test alone is weak, both together are not met on any drive of the matrix.  drifting (``rate_significance.drifting``)
    keeps out rates too small to matter.  cs: the calibration state; track: T (m)."""
    beta = rate_filter.beta
    seen, stretch_rate = _cal.stretches_see(params, cs, beta, track, CORROBORATED_STRETCH_Z)
    same_size = (CORROBORATED_FACTOR * jnp.abs(stretch_rate) > jnp.abs(beta)) & (
        jnp.abs(stretch_rate) < CORROBORATED_FACTOR * jnp.abs(beta))
    return _beyond(rate_filter, CORROBORATED_RATE_Z) & seen & same_size & _rate.drifting(params, rate_filter)


STRETCH_GATE = 3.0
"""A stretch whose rate is further than this many sigmas from the rate filter's counts as proportionally less
(``measure_rate``): a gentle curve the compass did not see biases a stretch by 1e-3."""


def stretch_rate(params, before, after, track):
    """The wheel heading's drift (rad/m) that a stretch completed in this sample says the ratio in force leaves, and
    its variance ((rad/m)^2): rate = (k - k_s) / T (``calibration.stretches_rate``'s sign), variance
    (cal_stretch_sigma / T)^2 / min(w, 1), w the stretch's intensity (the compass's straightness and its consistency
    with the previous stretch; EP 0619873 claims 6-11), found from the filtered ratio's weight (claim 13:
    W' = W (1 - w / cal_filter_stretches) + w).  before, after: the calibration state before and after this sample.
    Returns (rate, variance, whether a stretch completed: bool)."""
    done = after.updates > before.updates
    w = _safe_div(after.weight - before.weight, 1.0 - before.weight / params.cal_filter_stretches)
    w = jnp.clip(jnp.where(done, w, 0.0), 1e-12, 1.0)
    rate = _safe_div(before.ratio - after.prev_k, track)
    return rate, _safe_div(params.cal_stretch_sigma, track) ** 2 / w, done


def measure_rate(rate_filter, rate, variance, ok):
    """The rate filter's rate measured directly (rad/m, of ``variance``): a Kalman update with h = e_beta, the
    innovation's variance inflated beyond STRETCH_GATE sigmas.  Where the seed is silent: a straight stretch measures
    the wheels' drift from the pulse counts alone, the rate filter from the compass against the wheels; each
    stretch is one independent look at what the ratio in force leaves (docs/tuning.md, stop 54).  ok (bool): a stretch
    completed.  Returns the rate filter (an OffsetState)."""
    new = _offset.measure_state(rate_filter, "beta", rate, variance, STRETCH_GATE)
    return _offset.OffsetState(jnp.where(computed_once(ok), new.vector, rate_filter.vector))


def calibrate(params, calibration, config, odo, h_c, compass_ok, offset, steady, initialized):
    """EP 0619873's calibration, then the drift confirmed (the module docstring).  calibration: the calibration state
    before this sample; odo: ``odometer.odometer``'s dict; h_c (rad), compass_ok (bool); offset, steady: the rate and
    steady F-DELTA after this sample's update.  Returns (calibration state, offset, steady, the change of the wheel
    heading's rate per metre [rad/m], for the Kalman mode's beta)."""
    robust = config.robust
    # Only counts as they were measure the tyres: a burst the guard removed by rounding can miss by a pulse, and one
    # pulse in a stretch moved the ratio by 42 ppm, the odometer heading 2.9 deg over the next 4 minutes (independent
    # simulator, urban_hilly s61; docs/tuning.md, stop 89).  A stretch with a substituted sample is discarded.
    cal_state = _cal.calibration_step(
        params, calibration, pulses_left=odo["n_left"], pulses_right=odo["n_right"], d_t=odo["d_t"],
        compass_heading=h_c, compass_ok=compass_ok, odometer_ok=odo["counted"], enabled=config.calibration,
        robust=robust)
    if _fdelta.captures_drift(config):
        # A completed stretch measures the drift the ratio in force leaves, independently of the compass.
        offset = measure_rate(offset, *stretch_rate(params, calibration, cal_state, odo["track"]))
        # A large, significant drift of the wheel heading is the tyres': taken into the ratio at once.
        capture = computed_once(_rate.large_drift(params, offset) & _beyond(offset, _cal.CAPTURE_RATE_Z)
                                & (initialized > 0.5))
        # A smaller one the stretches corroborate: the heading follows the rate filter from here (the hold), and
        # later recalibrations restart the hold as after a large drift (the rate filter's since_drift).
        confirmed = computed_once(corroborated(params, cal_state, offset, odo["track"]) & ~capture
                                  & (initialized > 0.5))
        steady = _offset.restart_hold(steady, confirmed)
        offset = _offset.restart_hold(offset, confirmed)
        cal_state = _cal.capture_rate(params, cal_state, offset.beta, odo["track"], capture)
    # A new calibration changes the wheel heading's rate per metre; the offset's rate follows at once.
    rate_change = jnp.zeros_like(odo["track"])
    if config.calibration and robust:
        rel_left = cal_state.dpp_left / calibration.dpp_left - 1.0
        rel_right = cal_state.dpp_right / calibration.dpp_right - 1.0
        rate_change = (rel_left - rel_right) / odo["track"]
        offset = _offset.shift_rate(offset, rate_change)
        # A ratio still moving by more than RECALIBRATION_HOLD within filter_follow_hold_m of a large drift (a tyre
        # mismatch, captured) says the wheels drift: the steady filter follows the rate filter while the stretches
        # refine it.
        moving = jnp.abs(rel_left - rel_right) > RECALIBRATION_HOLD
        moving = moving & (offset.since_drift < params.filter_follow_hold_m)
        steady = _offset.restart_hold(steady, computed_once(moving))
    return cal_state, offset, steady, rate_change
