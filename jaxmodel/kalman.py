"""Kalman-filter mode, US 4,680,715.

PLACEHOLDER (issue 3): passes the dead-reckoned heading and position through.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class KalmanState(NamedTuple):
    x: jnp.ndarray  # east, m
    y: jnp.ndarray  # north, m


def init_kalman_state(params):
    z = jnp.zeros((), jnp.float64)
    return KalmanState(z, z)


def kalman_step(params, ks, *, dt, d_t, alpha, wheel_heading, compass_heading, compass_ok, e_c,
                fix_east, fix_north, fix_valid):
    """Returns (new KalmanState, heading [rad], x [m], y [m])."""
    x = ks.x + d_t * jnp.sin(wheel_heading)
    y = ks.y + d_t * jnp.cos(wheel_heading)
    return KalmanState(x, y), wheel_heading, x, y
