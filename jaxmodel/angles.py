"""Angle helpers: wrapping to (-pi, pi] and safe arithmetic for differentiable code.

SPEC §1: every difference of headings is wrapped before it is filtered or compared.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

PI = jnp.pi
TWO_PI = 2.0 * jnp.pi


def wrap(angle):
    """Wrap an angle (rad) to (-pi, pi]. Piecewise linear with unit slope, so gradients pass through."""
    wrapped = angle - TWO_PI * jnp.floor((angle + PI) / TWO_PI)  # [-pi, pi)
    return jnp.where(wrapped <= -PI, wrapped + TWO_PI, wrapped)


_SIN_TAYLOR = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(10))
"""Taylor coefficients of sin up to x^19: on [-pi/2, pi/2] the remainder is below 3e-16."""


def sin_polynomial(angle):
    """sin(angle) as a polynomial after reduction to [-pi/2, pi/2] (|error| < 2e-15 for |angle| < 50, differentiable).

    jnp.sin is a libm call per element under XLA:CPU, and XLA, counting it cheap, repeats it inside
    every kernel that uses its result: 22 times per step for the filter's tilt gain, a quarter of the
    robust step's time (docs/tuning.md, "Throughput").  Multiplications and additions cost nothing there.
    """
    x = wrap(angle)
    x = jnp.where(x > 0.5 * PI, PI - x, jnp.where(x < -0.5 * PI, -PI - x, x))
    x2 = x * x
    acc = _SIN_TAYLOR[-1]
    for c in reversed(_SIN_TAYLOR[:-1]):
        acc = acc * x2 + c
    return x * acc


def safe_div(num, den, eps=1e-12, fallback=0.0):
    """num/den where |den| > eps, else ``fallback``; double-where so neither branch makes a NaN gradient."""
    ok = jnp.abs(den) > eps
    den_safe = jnp.where(ok, den, 1.0)
    return jnp.where(ok, num / den_safe, fallback)


def safe_sqrt(x, floor=1e-300):
    """sqrt(max(x, 0)) with a finite gradient at and below zero (double-where)."""
    positive = x > floor
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)
