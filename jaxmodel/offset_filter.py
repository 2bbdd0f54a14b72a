"""F-DELTA as a robust three-state filter (US 4,734,863 FIG. 8G, where the seed leaves the filter open).

The seed low-passes DELTA = H_C - H_W with the distance constant T_C = D_N / (D_T F) and says
the filter "can be implemented ... in a variety of other filtering relationships depending on
the spectral characteristics of the errors" (col. 8).  Its own model of the wheel error is
"random start heading R" plus "drift D" that "changes slowly" (eq. 1-5): an offset and a rate.
We filter exactly that model, per travelled metre:

    offset  delta_{k+1} = delta_k + beta_k AD_k            (AD signed: reversing undoes it)
    rate    beta_{k+1}  = beta_k + w_beta                  (left/right tyre mismatch, slowly varying)
    compass c_{k+1}     = phi c_k + w_c, phi = exp(-|AD|/filter_gm_m)   (anomalies, dip: coloured)
    DELTA_k = delta_k + c_k + white compass error

with process noise ``filter_offset_psd`` per metre plus (``filter_turn_sigma`` alpha)^2 per turn on
the offset, ``filter_rate_psd`` per metre on the rate, and a compass noise of
``filter_compass_sigma_deg`` (plus ``filter_ec_weight`` E_C, FIG. 8C) counted once per
``filter_compass_corr_m`` metres, divided by the seed's factor F (FIG. 8E: F > 1 trusts the compass
more).  It is a three-state Kalman filter; with beta held at 0 and a fixed gain it is the seed's
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

import jax
import jax.numpy as jnp

from .angles import safe_div, wrap
from .params import deg

UNINITIALIZED_BOUND = jnp.pi
"""heading_bound (rad) before any absolute heading started the estimate: nothing supports it."""


class OffsetState(NamedTuple):
    """x = (delta, beta, c): F-DELTA (rad), its rate per signed metre (rad/m), the compass's coloured
    error (rad); P (3, 3) their covariance; ``disturbance`` the innovation averaged over
    filter_check_m (rad); ``since_absolute`` metres since the last absolute sample."""

    x: jnp.ndarray
    P: jnp.ndarray
    disturbance: jnp.ndarray
    since_absolute: jnp.ndarray

    @property
    def delta(self):
        return self.x[..., 0]


def init_offset_state(params):
    z = jnp.zeros((), jnp.float64)
    P = jnp.diag(jnp.stack([deg(params.filter_sigma0_deg) ** 2, params.filter_rate_sigma0 ** 2,
                            deg(params.filter_gm_sigma_deg) ** 2]))
    return OffsetState(jnp.zeros((3,), jnp.float64), P, z, z)


def start(params):
    """State when the first absolute heading starts the wheel heading (delta 0, prior covariance)."""
    return init_offset_state(params)


def predict(params, fs, ad_signed, d_t, alpha):
    """Propagate over one sample: AD (signed, m), |AD| (m) and the wheel turn alpha (rad).

    The coloured compass error is first-order Gauss-Markov over filter_gm_m metres of stationary
    sigma filter_gm_sigma_deg (anomalies and dip errors are fixed in space, so in distance).
    """
    phi = jnp.exp(-d_t / params.filter_gm_m)
    one, zero = jnp.ones_like(phi), jnp.zeros_like(phi)
    F = jnp.stack([jnp.stack([one, ad_signed, zero]), jnp.stack([zero, one, zero]), jnp.stack([zero, zero, phi])])
    q = jnp.stack([params.filter_offset_psd * d_t + (params.filter_turn_sigma * alpha) ** 2,
                   params.filter_rate_psd * d_t, deg(params.filter_gm_sigma_deg) ** 2 * (1.0 - phi * phi)])
    x = F @ fs.x
    P = F @ fs.P @ F.T + jnp.diag(q)
    return OffsetState(x, P, fs.disturbance, fs.since_absolute + d_t)


def update(params, fs, delta_meas, sigma, d_t, factor, ok):
    """Robust measurement update with DELTA (rad) of white sigma (rad) per kf_compass_corr_m metres.

    DELTA = delta + c + white noise.  Returns (new state, accepted weight in [0, 1]: 1 a clean
    sample, near 0 a rejected one).
    """
    h = jnp.array([1.0, 0.0, 1.0])
    nu = wrap(delta_meas - fs.x[0] - fs.x[2])
    p_hh = h @ fs.P @ h
    # Running agreement of DELTA with the wheels over filter_check_m metres.
    keep = jnp.exp(-d_t / params.filter_check_m)
    disturbance = jnp.where(ok, keep * fs.disturbance + (1.0 - keep) * nu, fs.disturbance)
    s2 = deg(params.filter_check_sigma_deg) ** 2
    gate2 = params.filter_gate_sigma ** 2
    z2 = disturbance ** 2 / (p_hh + s2)
    # Information counted once per kf_compass_corr_m metres: no gain while standing still.
    per_distance = jnp.maximum(1.0, safe_div(params.filter_compass_corr_m, d_t, eps=1e-9, fallback=1e12))
    r = sigma ** 2 * per_distance / jnp.maximum(factor, 1e-6) * (1.0 + z2 / gate2)
    r = r * jnp.maximum(1.0, nu ** 2 / (gate2 * (p_hh + r)))
    ph = fs.P @ h
    gain = ph / (p_hh + r)
    x = fs.x + gain * nu
    x = x.at[0].set(wrap(x[0]))
    P = fs.P - jnp.outer(gain, ph)
    P = 0.5 * (P + P.T)
    new = OffsetState(x, P, disturbance - (gain[0] + gain[2]) * nu, jnp.zeros_like(fs.since_absolute))
    old = OffsetState(fs.x, fs.P, disturbance, fs.since_absolute)
    out = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, old)
    weight = jnp.where(ok, 1.0 / (1.0 + z2 / gate2), 0.0)
    return out, weight


def shift_rate(fs, change_per_m):
    """The wheel heading's rate per metre changed by ``change_per_m`` (a new calibration): the offset's rate moves opposite."""
    return fs._replace(x=fs.x.at[1].add(-change_per_m))


def bound(fs, initialized):
    """Heading bound (rad): sqrt of the offset variance; UNINITIALIZED_BOUND before the start."""
    p = fs.P[0, 0]
    return jnp.where(initialized > 0.5, jnp.sqrt(jnp.maximum(p, 0.0)), UNINITIALIZED_BOUND)
