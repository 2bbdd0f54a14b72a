"""The adaptive complementary heading filter, US 4,734,863 FIG. 8D-8H and FIG. 8F.

DELTA = H_C - H_W, wrapped; F-DELTA follows DELTA with the distance constant
T_C = D_N / (D_T F) (FIG. 8G); EH = H_W + F-DELTA (FIG. 8H).  F adapts to the sensors'
error bounds: E_W from the wheel turns (FIG. 8D), E_C from the field magnitude (FIG. 8C),
and SDD, the fast-attack slow-decay deviation of DELTA (FIG. 8E/A).
"""

from __future__ import annotations

import jax.numpy as jnp

from .angles import safe_div, wrap
from .params import deg


def wheel_error_bound(params, e_w, alpha, d_t):
    """E_W after a step (FIG. 8D): E_WA = E_W + |alpha K|, E_W = E_WA (F_E - 1)/F_E with F_E = D_N/D_T; rad."""
    e_wa = e_w + jnp.abs(alpha * params.wheel_error_K)
    decay = jnp.clip(1.0 - d_t / params.D_N, 0.0, 1.0)  # (F_E - 1)/F_E, written so D_T = 0 is safe
    return e_wa * decay


def deviation_of_three(deltas):
    """SD_N: standard deviation of the last three DELTA values (FIG. 8E/A block 1), wrap-safe.

    ``deltas`` has shape (3,); differences are taken relative to the newest, wrapped, so the
    statistic does not jump when DELTA crosses +-pi.
    """
    rel = wrap(deltas - deltas[0])
    mean = jnp.mean(rel)
    var = jnp.mean((rel - mean) ** 2)
    # sqrt with a safe gradient at zero variance (three equal DELTAs)
    ok = var > 1e-30
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, var, 1.0)), 0.0)


def update_sdd(params, sdd_old, sd_n):
    """SDD = SD_N/T + (T-1)/T SDD_O, then fast attack: SDD = max(SD_N, SDD) (FIG. 8E/A blocks 2-4)."""
    t = params.sdd_T
    sdd = sd_n / t + (t - 1.0) / t * sdd_old
    return jnp.maximum(sd_n, sdd)


def time_constant_factor(params, sdd, e_w, e_c):
    """F from E_h = SDD K (E_W - E_C) (FIG. 8E blocks 2-5).

    E_h > 0 (wheels worse): F = (E_h + K1)/K1 >= 1, the compass gets more weight.
    E_h <= 0 (compass worse): F = K2/(|E_h| + K2) <= 1.  Seed defect: FIG. 8E block 5 prints
    K2/(E_h + K2), which for E_h < 0 would give F > 1 (more compass weight when the compass is
    worse) and a pole at E_h = -K2; the stated intent needs the magnitude, so |E_h| is used.
    """
    e_h = sdd * params.heading_error_K * (e_w - e_c)
    return jnp.where(e_h > 0.0, (e_h + params.K1) / params.K1, params.K2 / (jnp.abs(e_h) + params.K2))


MAP_HEADING_LIMIT_RAD = 1e4
"""The largest map heading (rad, either sign) taken as a heading: a few thousand turns, where wrap's reduction
still loses under 3e-12 rad; beyond is a corrupt sample, treated as no map heading."""


def select_absolute_heading(params, h_c, h_w, estimate, map_heading, map_valid, unreliable_area):
    """Absolute direction signal and DELTA (FIG. 5, FIG. 8F).

    The map heading replaces the compass only when the vehicle is on a street (map_valid), the
    area is flagged compass-unreliable, and the street agrees with the current estimate within
    map_threshold_deg in either direction (two-way street, FIG. 7 block 7D).  Returns
    (absolute heading [rad], DELTA [rad], map_used [bool]).
    """
    # A map heading beyond MAP_HEADING_LIMIT_RAD is no heading: wrap of 1e300 rad is rounding noise of any
    # size (x - 2 pi floor(x / 2 pi) cancels 1e300 against 1e300), and it reached the Kalman course
    # measurement as -4e230 rad (hypothesis, stop 48).
    map_plausible = jnp.isfinite(map_heading) & (jnp.abs(map_heading) <= MAP_HEADING_LIMIT_RAD)
    map_heading = jnp.where(map_plausible, map_heading, 0.0)
    forward = wrap(map_heading - estimate)
    backward = wrap(map_heading + jnp.pi - estimate)
    use_backward = jnp.abs(backward) < jnp.abs(forward)
    street = wrap(jnp.where(use_backward, map_heading + jnp.pi, map_heading))
    agrees = jnp.minimum(jnp.abs(forward), jnp.abs(backward)) < deg(params.map_threshold_deg)
    map_used = (map_valid > 0.5) & (unreliable_area > 0.5) & agrees & map_plausible
    absolute = jnp.where(map_used, street, h_c)
    return absolute, wrap(absolute - h_w), map_used


def filter_gain(params, d_t, factor, distance_since_start):
    """1/T_C = D_T F / D_N (FIG. 8G block 1), never below D_T / (distance since start).

    The floor makes F-DELTA the distance-weighted mean of DELTA until the vehicle has driven
    D_N/F, so the first compass samples do not stay in the estimate for kilometres; it is at
    most 1 (T_C >= 1).
    """
    nominal = d_t * factor / params.D_N
    start_up = safe_div(d_t, distance_since_start, eps=1e-9, fallback=1.0)
    return jnp.clip(jnp.maximum(nominal, start_up), 0.0, 1.0)


def update_f_delta(f_delta, delta, gain):
    """F-DELTA = DELTA/T_C + (T_C-1)/T_C F-DELTA (FIG. 8G block 2), as F += wrap(DELTA - F)/T_C (SPEC §1)."""
    return wrap(f_delta + gain * wrap(delta - f_delta))


def heading_bound(sdd, e_w, e_c):
    """Heading error bound (rad) behind the reliability output (line 27 of FIG. 4).

    Our reading: the two sensor bounds combine like parallel estimates, E_W E_C/(E_W+E_C),
    and SDD adds the observed disagreement between them.
    """
    return sdd + safe_div(e_w * e_c, e_w + e_c)


def reliability(params, bound):
    """heading_reliability in (0, 1]: 1/(1 + bound/reliability_scale_deg)."""
    return 1.0 / (1.0 + bound / deg(params.reliability_scale_deg))
