"""Whether the wheels drift: the rate filter's rate, judged by its size and its significance.

The rate filter of jaxmodel/offset_filter.py carries F-DELTA's rate per metre (beta): a tyre mismatch or a wrong
track turns the wheel heading steadily, and the compass sees it as a steady change of F-DELTA.  These tests read that
rate: large enough to lock the compass out over filter_reacquire_m (``drifting``), sure enough to act on
(``significant``, ``follow_weight``: how much the steady filter takes the rate filter's state), and large like a tyre
mismatch rather than a grade's dip error (``large_drift``: the calibration captures it, the follow hold starts).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .params import deg


def drifting(params, rate_filter):
    """Whether the rate filter's rate turns F-DELTA by more than filter_reacquire_drift_deg over
    filter_reacquire_m (bool): a disagreement with the compass is then the wheels' (a lock-out), not the
    compass's."""
    return jnp.abs(rate_filter.beta) * params.filter_reacquire_m > deg(params.filter_reacquire_drift_deg)


def drifting_significantly(params, rate_filter):
    """``drifting`` with a rate the filter is sure of (``significant``, bool): what lets a rejected compass restart
    the filter after filter_reacquire_m (``offset_filter.update``'s ``drift_significant``)."""
    return drifting(params, rate_filter) & significant(params, rate_filter)


def rate_z(rate_filter):
    """The rate's significance, signed like the rate: beta / sigma_beta (1)."""
    return rate_filter.beta / jnp.sqrt(jnp.maximum(rate_filter.p11, 1e-300))


def followed_since_before(rate_filter, steady, lead_m):
    """Whether the rate filter has followed the compass (its ``accepted_m``) ``lead_m`` metres longer than the steady
    filter has rejected it (its ``rejected_m``): its rate was learned before the steady filter's disagreement began
    (bool)."""
    return rate_filter.accepted_m > steady.rejected_m + lead_m


FOLLOW_STEEPNESS = 8.0
"""Slope of follow_weight per unit of z (8: the weight goes 0.018 -> 0.98 between z - 0.5 and z + 0.5)."""


def follow_weight(params, rate_filter, significance=None):
    """How much the steady F-DELTA takes the rate filter's state this sample, in [0, 1].

    A smooth step in the rate's significance z = |beta| / sigma_beta, 0.5 at z =
    ``significance`` (default filter_rate_significance) and 1e-7 at z = 0 (so gradients exist across the switch; at
    10 Hz the pull of an insignificant rate is nil, of a significant one complete within samples).
    """
    significance = params.filter_rate_significance if significance is None else significance
    return jax.nn.sigmoid(FOLLOW_STEEPNESS * (jnp.abs(rate_z(rate_filter)) - significance))


def significant(params, rate_filter):
    """Whether the rate filter's rate is beyond filter_rate_significance of its sigmas (follow_weight above 1/2)."""
    return follow_weight(params, rate_filter) > 0.5


def large_drift(params, rate_filter):
    """Whether the rate filter's rate is significant (follow_weight above 1/2) and larger than
    filter_follow_hold_rate (bool): the wheels drift as a tyre mismatch makes them, beyond what dip errors on
    grades look like.  It starts a capture of the drift into the left/right ratio (``calibration.capture_rate``),
    the window in which recalibrations restart the steady filter's follow hold
    (``offset_filter.count_since_large_drift``), and, with the calibration off, the hold itself (``follow.follow``)."""
    return significant(params, rate_filter) & (jnp.abs(rate_filter.beta) > params.filter_follow_hold_rate)


LAG_DRIFT_DEG = 0.8
"""``steady_lags``: the rate filter's rate turns F-DELTA by more than this over filter_reacquire_m (deg; 14 µrad/m),"""
LAG_Z = 1.5
"""... at more than this many of its sigmas,"""
LAG_LEAD_M = 100.0
"""... and that filter has followed the compass for this many metres (m) longer than the steady one has rejected it."""


def steady_lags(params, rate_filter, steady):
    """Whether the steady F-DELTA disagrees with the compass because it lags the wheels' drift (bool): the rate filter
    has followed the compass (its ``accepted_m``) since before the steady filter began to reject it (its
    ``rejected_m``, LAG_LEAD_M), with a rate beyond LAG_Z sigmas that turns F-DELTA by LAG_DRIFT_DEG over
    filter_reacquire_m.  The steady filter is then not hardened against the compass (``offset_filter.update``'s
    ``drifting``).

    Where the seed is silent.  A parameter file whose left/right ratio is 30 ppm off the tyres' drifts the wheels by
    19 µrad/m (1.1 deg/km): under ``drifting``'s 2 deg per filter_reacquire_m, the steady filter (no rate) lagged the
    drift by 2-3 deg, its compass hardened as a persistent compass error, and it never took the compass back
    (independent simulator, highway seed 30: 23 deg off after 27 km, 12.9 deg RMSE; 4.1 with this, the rate filter
    1.4).  A shifted hard iron that both filters rejected, the rate filter restarting on it, is not let in: the rate
    filter has not followed the compass since before the steady one rejected it (highway/hard_iron_shift/103 1.85 deg
    with this, 8.0 with ``drifting`` at 0.8 deg; docs/tuning.md, stop 70).  rate_filter, steady: OffsetStates (the
    rate filter after this sample's update, the steady one before it)."""
    return (followed_since_before(rate_filter, steady, LAG_LEAD_M)
            & (jnp.abs(rate_filter.beta) * params.filter_reacquire_m > deg(LAG_DRIFT_DEG))
            & (rate_filter.beta ** 2 > LAG_Z ** 2 * rate_filter.p11))
