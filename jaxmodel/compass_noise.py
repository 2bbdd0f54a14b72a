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


SPARSE_AFTER_S = 0.105
"""A 10-Hz log's sample interval at most (0.096-0.104 s): ``samples_per_measurement`` counts a compass reading for the
samples of at least this length that it stands for."""
STANDS_FOR_S = 1.0
"""The longest interval (s) one compass reading stands for: a reading after a dropout is one reading."""


def samples_per_measurement(corr_m, distance_m, dt, standing=1e12, reading_dt=None):
    """How many samples make one independent compass measurement: one per ``corr_m`` metres of |distance_m|
    (``standing`` where it is zero: no information from repeating a reading) and at most one per COMPASS_CORR_S
    seconds of ``dt`` (the sample's time step, s; None: not counted in time).

    ``reading_dt`` (s; None: ``dt``) the interval since the previous compass reading (``compass.reading_interval``): a
    compass logged slower than the wheels (NaN between its readings) is counted per reading interval, and each
    reading for the log samples it stands for (its interval, at most STANDS_FOR_S, over the sample's, at least
    SPARSE_AFTER_S), as a logger that held the reading would have it counted.  Counted once per sample, a 1-Hz compass
    in a 10-Hz log gave the filters a tenth of its information, whose errors are correlated over seconds (independent
    simulator, diagnosis seeds 1-4 and 28-33: 10-Hz compass 1.1069 deg, 1 Hz held 1.1416, 1 Hz with NaN between 1.2055;
    docs/tuning.md, stop 78).  A log whose every sample has a reading is counted as before."""
    per = jnp.maximum(1.0, safe_div(corr_m, jnp.abs(distance_m), eps=1e-9, fallback=standing))
    if dt is None:
        return per
    interval = dt if reading_dt is None else reading_dt
    per = jnp.maximum(per, safe_div(COMPASS_CORR_S, interval, eps=1e-9, fallback=1.0))
    if reading_dt is not None:
        stands_for = jnp.minimum(reading_dt, STANDS_FOR_S) / jnp.maximum(dt, SPARSE_AFTER_S)
        per = per / jnp.maximum(stands_for, 1.0)
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
