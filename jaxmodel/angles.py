"""Angle helpers: wrapping to (-pi, pi] and safe arithmetic for differentiable code.

SPEC §1: every difference of headings is wrapped before it is filtered or compared.
"""

from __future__ import annotations

import jax.numpy as jnp

PI = jnp.pi
TWO_PI = 2.0 * jnp.pi


def wrap(angle):
    """Wrap an angle (rad) to (-pi, pi]. Piecewise linear with unit slope, so gradients pass through."""
    wrapped = angle - TWO_PI * jnp.floor((angle + PI) / TWO_PI)  # [-pi, pi)
    return jnp.where(wrapped <= -PI, wrapped + TWO_PI, wrapped)


def safe_div(num, den, eps=1e-12, fallback=0.0):
    """num/den where |den| > eps, else ``fallback``; double-where so neither branch makes a NaN gradient."""
    ok = jnp.abs(den) > eps
    den_safe = jnp.where(ok, den, 1.0)
    return jnp.where(ok, num / den_safe, fallback)


def safe_sqrt(x, floor=1e-300):
    """sqrt(max(x, 0)) with a finite gradient at and below zero (double-where)."""
    positive = x > floor
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)
