"""What one compass sample tells a heading filter: its white noise, and how many samples make one measurement.

Shared by F-DELTA (``offset_filter``, ``f_delta``), the field magnitude's reading (``field_tilt``) and the Kalman mode
(``kalman``): each counts the compass's white error once per ``*_compass_corr_m`` metres and once per COMPASS_CORR_S
seconds at most, of the sigma ``compass_sigma`` gives (US 4,734,863 FIG. 8C's E_C among its terms).
"""

from __future__ import annotations

import jax.numpy as jnp

from .angles import safe_div
from .params import deg

COMPASS_CORR_S = 0.09
"""The compass's white noise is counted at most once per this many seconds (``offset_filter.update``'s ``dt``): the
filter's constants were fitted on 10-Hz logs (samples 0.096-0.104 s apart, which this leaves as they were), and a
50-Hz log of the same drive must not give the filter five times the compass information (its errors are not white at
50 Hz: stop 35 measured 0.47 -> 0.79 deg on highway/baseline/101 logged at 50 Hz without this, 0.68 with it)."""


def samples_per_measurement(corr_m, distance_m, dt, standing=1e12):
    """How many samples make one independent compass measurement: one per ``corr_m`` metres of |distance_m|
    (``standing`` where it is zero: no information from repeating a reading) and at most one per COMPASS_CORR_S
    seconds of ``dt`` (s; None: not counted in time)."""
    per = jnp.maximum(1.0, safe_div(corr_m, jnp.abs(distance_m), eps=1e-9, fallback=standing))
    if dt is not None:
        per = jnp.maximum(per, safe_div(COMPASS_CORR_S, dt, eps=1e-9, fallback=1.0))
    return per


def compass_sigma(params, e_c, turn_rate):
    """The compass's white noise sigma (rad) for one sample: ``filter_compass_sigma_deg``, ``filter_ec_weight``
    E_C (FIG. 8C) and ``filter_compass_lag_s`` times the wheels' turn rate (rad/s), added in quadrature.

    Where the seed is silent: a magnetometer that filters its readings lags in turns by its time constant times
    the turn rate (0.7 s and 20 deg/s: 14 deg), and in a turn the car rolls, so the turns' compass samples
    are the least trustworthy; the wheels carry the heading through a turn.  0.5 s was chosen on the tuning
    seeds of the matrix (no lag there: 0.3-0.7 s equal, geometric mean 0.979 -> 0.965 deg; docs/tuning.md, stop 29).
    """
    return jnp.sqrt(deg(params.filter_compass_sigma_deg) ** 2 + (params.filter_ec_weight * e_c) ** 2
                    + (params.filter_compass_lag_s * turn_rate) ** 2)
