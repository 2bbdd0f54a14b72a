"""F-DELTA as a robust two-state filter (US 4,734,863 FIG. 8G, where the seed leaves the filter open).

The seed low-passes DELTA = H_C - H_W with the distance constant T_C = D_N / (D_T F) and says
the filter "can be implemented ... in a variety of other filtering relationships depending on
the spectral characteristics of the errors" (col. 8).  Its own model of the wheel error is
"random start heading R" plus "drift D" that "changes slowly" (eq. 1-5): an offset and a rate.
We filter exactly that model, per travelled metre:

    offset  delta_{k+1} = delta_k + beta_k AD_k            (AD signed: reversing undoes it)
    rate    beta_{k+1}  = beta_k + w_beta                  (left/right tyre mismatch, slowly varying)
    DELTA_k = delta_k + compass error

with process noise ``filter_offset_psd`` per metre plus (``kf_turn_sigma`` alpha)^2 per turn on
the offset, ``filter_rate_psd`` per metre on the rate, and a compass noise of
``kf_compass_sigma_deg`` (plus ``kf_compass_ec_weight`` E_C, FIG. 8C) counted once per
``kf_compass_corr_m`` metres, divided by the seed's factor F (FIG. 8E: F > 1 trusts the compass
more).  It is a two-state Kalman filter; with beta held at 0 and a fixed gain it is the seed's
first-order filter.

Robustness, where the seed is silent (its FIG. 3A shows dip errors and 360-degree spikes):

* disturbance detection by agreement with the wheels: ``disturbance`` is the innovation
  DELTA - delta averaged over ``filter_check_m`` metres; clean compass samples keep it within
  their noise, an anomaly or a dip error moves it by degrees in tens of metres, while the
  wheels say the heading did not change.  The compass variance is inflated by
  1 + (disturbance^2 / (P + s^2)) / ``filter_gate_sigma``^2, s = ``filter_check_sigma_deg``;
* a soft innovation gate on each sample (variance inflated beyond ``filter_gate_sigma``);
* the variance P of the offset grows while the compass is rejected or missing, so the gate
  widens and a clean compass is taken back within metres; sqrt(P) is the heading bound behind
  ``heading_reliability``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import safe_div, wrap
from .packed import packed_state
from .params import deg

UNINITIALIZED_BOUND = jnp.pi
"""heading_bound (rad) before any absolute heading started the estimate: nothing supports it."""


class OffsetFields(NamedTuple):
    delta: jnp.ndarray    # F-DELTA: estimated true heading minus wheel heading, rad
    beta: jnp.ndarray     # its rate per signed metre driven, rad/m
    p00: jnp.ndarray      # covariance of (delta, beta)
    p01: jnp.ndarray
    p11: jnp.ndarray
    disturbance: jnp.ndarray  # innovation averaged over filter_check_m, rad
    since_absolute: jnp.ndarray  # m driven since the last accepted absolute sample


OffsetState = packed_state(OffsetFields, "OffsetState", "State of the robust F-DELTA filter (one float64 vector).")
OffsetState.__module__ = __name__


def init_offset_state(params):
    z = jnp.zeros((), jnp.float64)
    return OffsetState.pack(OffsetFields(z, z, deg(params.kf_heading_sigma0_deg) ** 2, z,
                                         params.filter_rate_sigma0 ** 2, z, z))


def start(params):
    """State when the first absolute heading starts the wheel heading (delta 0, prior covariance)."""
    return init_offset_state(params)


def predict(params, fs, ad_signed, d_t, alpha):
    """Propagate over one sample: AD (signed, m), |AD| (m) and the wheel turn alpha (rad)."""
    f = fs.fields()
    delta = f.delta + f.beta * ad_signed
    p00 = (f.p00 + 2.0 * f.p01 * ad_signed + f.p11 * ad_signed ** 2 + params.filter_offset_psd * d_t
           + (params.kf_turn_sigma * alpha) ** 2)
    p01 = f.p01 + f.p11 * ad_signed
    p11 = f.p11 + params.filter_rate_psd * d_t
    return OffsetState.pack(f._replace(delta=delta, p00=p00, p01=p01, p11=p11,
                                       since_absolute=f.since_absolute + d_t))


def update(params, fs, delta_meas, sigma, d_t, factor, ok):
    """Robust measurement update with DELTA (rad) of white sigma (rad) per kf_compass_corr_m metres.

    Returns (new state, accepted weight in [0, 1]: 1 a clean sample, near 0 a rejected one).
    """
    f = fs.fields()
    nu = wrap(delta_meas - f.delta)
    # Running agreement of DELTA with the wheels over filter_check_m metres.
    keep = jnp.exp(-d_t / params.filter_check_m)
    disturbance = jnp.where(ok, keep * f.disturbance + (1.0 - keep) * nu, f.disturbance)
    s2 = deg(params.filter_check_sigma_deg) ** 2
    gate2 = params.filter_gate_sigma ** 2
    z2 = disturbance ** 2 / (f.p00 + s2)
    # Information counted once per kf_compass_corr_m metres: no gain while standing still.
    per_distance = jnp.maximum(1.0, safe_div(params.kf_compass_corr_m, d_t, eps=1e-9, fallback=1e12))
    r = sigma ** 2 * per_distance / jnp.maximum(factor, 1e-6) * (1.0 + z2 / gate2)
    s = f.p00 + r
    r = r * jnp.maximum(1.0, nu ** 2 / (gate2 * s))
    s = f.p00 + r
    k0 = f.p00 / s
    k1 = f.p01 / s
    new = f._replace(
        delta=wrap(f.delta + k0 * nu), beta=f.beta + k1 * nu,
        p00=f.p00 - k0 * f.p00, p01=f.p01 - k0 * f.p01, p11=f.p11 - k1 * f.p01,
        disturbance=disturbance - k0 * nu, since_absolute=jnp.zeros_like(f.since_absolute))
    out = OffsetState.pack(OffsetFields(*[jnp.where(ok, a, b) for a, b in zip(new, f._replace(disturbance=disturbance))]))
    weight = jnp.where(ok, 1.0 / (1.0 + z2 / gate2), 0.0)
    return out, weight


def shift_rate(fs, change_per_m):
    """The wheel heading's rate per metre changed by ``change_per_m`` (a new calibration): the offset's rate moves opposite."""
    f = fs.fields()
    return OffsetState.pack(f._replace(beta=f.beta - change_per_m))


def bound(fs, initialized):
    """Heading bound (rad): sqrt of the offset variance; UNINITIALIZED_BOUND before the start."""
    p = fs.fields().p00
    return jnp.where(initialized > 0.5, jnp.sqrt(jnp.maximum(p, 0.0)), UNINITIALIZED_BOUND)
