"""The compass's soft-iron deviation read from the field's magnitude per heading, without the wheels.

A linear distortion S of the horizontal field (the vehicle's steel, magnetised by the earth's field) turns and scales
what the compass reads, and the two are tied.  For m = S b with |b| = B at raw angle A, m x dm/dA = det(S) B^2, so
the measured angle phi turns at dphi/dA = det(S) B^2 / |m|^2: where the field reads strong, the compass turns slowly.
To first order in S - I, with

    ln|m(phi)| = c0 + a2 cos 2 phi + b2 sin 2 phi,

the deviation phi - A is the conjugate harmonic, -a2 sin 2 phi + b2 cos 2 phi; a symmetric S = [[1 + e1, e2],
[e2, 1 - e1]] gives a2 = e1, b2 = e2 (and the deviation e2 cos 2A - e1 sin 2A of jaxmodel/soft_iron.py's docstring).
US 4,734,863 FIG. 8C measures the expected magnitude B_E "for each of those known headings" (claim 13) and FIG. 8A
applies a deviation table from the compass's calibration; here the one is read from the other while driving, the
way a magnetometer is calibrated from its ellipse.  On the matrix's soft-iron drives a least-squares fit of ln|B| over
one drive's samples gives (a2, b2) within 0.002-0.007 of (e1, e2) in urban, mixed and parking (docs/tuning.md, stop 41).

Estimator: a recursive least-squares regression of ln|B| on (1, cos A, sin A, cos 2A, sin 2A), A the compass heading
before any soft-iron correction, the first harmonic a nuisance (a hard-iron residual, a grade shows cos A), each sample
weighted by the metres it drove, over samples with a valid compass within FIELD_GATE of B_E per heading (anomalies and
standstill teach nothing), ridge prior RIDGE_M on the harmonics.  The sums start again when B_E per heading does (a
hard-iron restart, a lost filter's restart) and when the shift learner moves the offsets.  Applied only when

* the drive's headings span enough of the circle: the mean resultant lengths |E[exp(iA)]| and |E[exp(2iA)]| both
  below COVER (a highway seen along one arc cannot tell the second harmonic from the first or from the terrain), and
* (a2, b2) is significant: its Mahalanobis length z against the covariance (residual variance) x CORRELATION_M x
  (normal matrix)^-1 (terrain and anomalies make the residuals correlated over ~100 m), soft-thresholded by Z0: the
  deviation applied is scaled by max(z - Z0, 0) / z.

A calibrated compass's deviation table (``deviation_deg``, identification/compass_fit.py) has taken its second
harmonic out of H_C already (``table_deviation``): the ridge prior and the significance test are centred on it and
only the difference is applied, so the soft iron is not taken out twice (stop 42: mixed/soft_iron/103 with its exact
table 0.63 deg, taken out twice 1.36 deg).

The wheels' learner (jaxmodel/soft_iron.py) then regresses what is left.  Where it falls short: the dip of a level
compass on a slope also changes the magnitude, and on a route whose grade depends on its direction that shows as a
second harmonic (real there, but not the same elsewhere): the significance and coverage tests are what keep it out.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from . import normal_equations as _ne
from .packed import computed_once, packed_state

RIDGE_M = 200.0
"""Ridge prior on the harmonics' coefficients (m of samples at a unit regressor)."""
FIELD_GATE = 0.08
"""Samples whose |ln(|B| / B_E)| is beyond this (B_E per heading) are not used: anomalies, a parked truck."""
COVER = 0.65
"""Applied only when |E[exp(iA)]| and |E[exp(2iA)]| over the samples are both below this."""
CORRELATION_M = 100.0
"""Metres over which the residuals of ln|B| are taken as correlated (the significance test's sample size)."""
Z0 = 3.0
"""Mahalanobis length of (a2, b2) by which the applied deviation is soft-thresholded."""

_K = 5  # regressors: 1, cos A, sin A, cos 2A, sin 2A (the second harmonic last: its block of the Cholesky factor)


SoftFieldFields = NamedTuple("SoftFieldFields", [(name, jnp.ndarray) for name in (*_ne.sum_fields(_K), "ll")])
SoftFieldFields.__doc__ = """Sums over the used samples, weighted by metres: n_ij of x_i x_j (i <= j), b_i of
x_i ln|B| (the normal equations, jaxmodel/normal_equations.py), ll of ln|B|^2; x = (1, cos A, sin A, cos 2A, sin 2A)."""


SoftFieldState = packed_state(SoftFieldFields, "SoftFieldState",
                              "Sums of the regression of ln|B| on the heading's harmonics (soft iron from the field).")


def init_soft_field_state() -> SoftFieldState:
    return SoftFieldState.pack(SoftFieldFields(*([jnp.zeros((), jnp.float64)] * len(SoftFieldFields._fields))))


def update(sf, harmonics_of_a, b_m, b_e, d_t, use, reset):
    """One sample: ``harmonics_of_a`` = ``soft_iron.harmonics(A)``, (sin A, cos A, sin 2A, cos 2A) of the compass
    heading A before any soft-iron correction, |B| ``b_m`` and B_E per heading ``b_e`` (compass units), ``d_t`` (m),
    ``use`` (bool) the compass valid and the vehicle moving, ``reset`` (bool) start the sums again first.  Returns the
    state."""
    # A sample not in use may carry anything (a heading of 1e308): it must not reach the sums, not even times 0.
    s1, c1, s2, c2 = (jnp.where(use, v, 0.0) for v in harmonics_of_a)
    x = (jnp.ones_like(s2), c1, s1, c2, s2)
    safe_m = jnp.where(use, b_m, 1.0)
    near = jnp.abs(jnp.log(safe_m / jnp.where(use, b_e, 1.0))) < FIELD_GATE
    w = jnp.where(use & near, d_t, 0.0)
    ln_b = jnp.log(safe_m)
    terms = [x[i] * x[j] for i, j in _ne.pairs(_K)] + [x[i] * ln_b for i in range(_K)] + [ln_b * ln_b]
    vector = jnp.where(computed_once(reset)[..., None], 0.0, sf.vector)
    return SoftFieldState(vector + w[..., None] * jnp.stack(terms, axis=-1))


def _cholesky_solve(f, centre):
    """The normal equations with the ridge prior RIDGE_M centred at (0, 0, 0, a2_0, b2_0) = ``centre``, by a Cholesky
    factor written out (jaxmodel/normal_equations.py).  Returns (c, y, low) as lists: the coefficients, the
    forward-solved right-hand side y = L^-1 (b + R c_0) (so L^T c = y) and the factor L."""
    m = _ne.normal_matrix(f, _K, [1e-6] + [RIDGE_M] * (_K - 1))
    rhs = [f.b0, f.b1, f.b2, f.b3 + RIDGE_M * centre[0], f.b4 + RIDGE_M * centre[1]]
    return _ne.cholesky_solve(m, rhs)


NO_TABLE = (0.0, 0.0)
"""``coefficients``' ``taken_out`` for a compass whose deviation table has no second harmonic."""


def coefficients(sf, taken_out=NO_TABLE):
    """(p, q) (rad): the deviation p sin 2A + q cos 2A still to subtract from the compass heading A.

    The field's magnitude reads the whole soft iron, (p, q) = (-a2, b2); ``taken_out`` = (p_0, q_0) is what the
    deviation table already took out of H_C (``table_deviation``).  What is left, (p - p_0, q - q_0), is scaled by the
    significance test's soft threshold and is zero while the headings do not cover the circle: without evidence
    the table stands (a calibrated compass is not corrected twice).  The ridge prior is centred on the table."""
    f = sf.fields()
    centre = (-taken_out[0], taken_out[1])  # (a2_0, b2_0)
    c, y, low = _cholesky_solve(f, centre)
    # Residual sum of squares at the ridge solution, with N + R = L L^T and (N + R) c = b + R c_0:
    # ll - 2 c.b + c.N.c = ll - c.b - c.R.(c - c_0).
    rss = (f.ll - sum(ci * bi for ci, bi in zip(c, (f.b0, f.b1, f.b2, f.b3, f.b4)))
           - RIDGE_M * (sum(ci * ci for ci in c[1:]) - c[3] * centre[0] - c[4] * centre[1]))
    weight = f.n00
    variance = jnp.maximum(rss, 0.0) / jnp.maximum(weight, 1.0) + 1e-8
    # (a2, b2)'s inverse covariance is L22 L22^T / (variance x CORRELATION_M), L22 the factor's last block, and
    # L22^T (a2 - a2_0, b2 - b2_0) = (y3, y4) - L22^T (a2_0, b2_0) (rows 3-4 of L^T c = y): z^2 is its square over
    # the scale.
    u3 = y[3] - low[3][3] * centre[0] - low[4][3] * centre[1]
    u4 = y[4] - low[4][4] * centre[1]
    z = jnp.sqrt((u3 * u3 + u4 * u4) / (variance * CORRELATION_M) + 1e-30)
    keep = jnp.maximum(z - Z0, 0.0) / z
    keep = jnp.where(_covered(f), keep, 0.0)
    return -keep * (c[3] - centre[0]), keep * (c[4] - centre[1])


def _covered(f):
    """Whether the headings span enough of the circle: |E[exp(iA)]| and |E[exp(2iA)]| both below COVER."""
    spread = jnp.maximum(f.n01 * f.n01 + f.n02 * f.n02, f.n03 * f.n03 + f.n04 * f.n04)
    return spread < (COVER * COVER) * f.n00 * f.n00  # (no sample: 0 < 0 is not covered)


def magnitude_without_first_harmonic(sf, harmonics_of_a):
    """(c0 + a2 cos 2A + b2 sin 2A, covered): the regression's ln|B| at compass heading A without its first
    harmonic, which is what a grade, a roll or a hard-iron residual add (jaxmodel/field_tilt.py reads |B| against it),
    and whether the headings cover the circle (``coefficients``' test): on one arc the harmonics are not told apart
    from the constant.  The ridge prior is centred on 0 (the soft iron itself, not beyond a table)."""
    f = sf.fields()
    c, _, _ = _cholesky_solve(f, (0.0, 0.0))
    s2, c2 = harmonics_of_a[-2:]
    return c[0] + c[3] * c2 + c[4] * s2, _covered(f)


def deviation(sf, harmonics_of_a, taken_out=NO_TABLE):
    """The deviation (rad) at a compass heading A given as ``soft_iron.harmonics(A)``, beyond what the deviation
    table took out (``taken_out``, see ``coefficients``); to subtract from H_C."""
    p, q = coefficients(sf, taken_out)
    s, c = harmonics_of_a[-2:]
    return p * s + q * c


def table_deviation(deviation_deg, offset):
    """(p_0, q_0) (rad): the deviation p_0 sin 2A + q_0 cos 2A the 36-entry deviation table (deg) took out of H_C
    already, A = raw + ``offset`` (rad; V - R of FIG. 8A).  H_C adds deviation(raw) (US 4,734,863 FIG. 8A block 4),
    i.e. takes out -deviation; its second harmonic d_s sin 2 raw + d_c cos 2 raw is the soft iron's (Archibald
    Smith's D and E, identification/compass_fit.py), least squares over the table's entries, turned by 2 offset
    into A's frame.  A table without a second harmonic gives (0, 0)."""
    table = jnp.radians(jnp.asarray(deviation_deg, jnp.float64))
    n = table.shape[-1]
    raw = jnp.arange(n) * (2.0 * jnp.pi / n)
    d_s = (2.0 / n) * jnp.sum(table * jnp.sin(2.0 * raw), axis=-1)
    d_c = (2.0 / n) * jnp.sum(table * jnp.cos(2.0 * raw), axis=-1)
    c2, s2 = jnp.cos(2.0 * offset), jnp.sin(2.0 * offset)
    return -(d_s * c2 + d_c * s2), -(d_c * c2 - d_s * s2)
