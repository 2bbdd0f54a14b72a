"""Continuous left/right distance-per-pulse calibration, EP 0619873.

PLACEHOLDER (issue 3): the state carries the current correction; the update is not yet
implemented, so dpp_left/dpp_right stay at their parameter values.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class CalibrationState(NamedTuple):
    dpp_left: jnp.ndarray   # m per pulse, current
    dpp_right: jnp.ndarray  # m per pulse, current


def init_calibration_state(params):
    return CalibrationState(dpp_left=jnp.asarray(params.dpp_left, jnp.float64),
                            dpp_right=jnp.asarray(params.dpp_right, jnp.float64))


def calibration_step(params, cs, *, pulses_left, pulses_right, d_t, compass_delta, compass_ok, odometer_ok, enabled):
    """One sample of the calibration. pulses_*: decoded pulse increments of this sample."""
    return cs
