"""The compass's heading-dependent deviation (soft iron), learned online from the wheels' turns.

A soft-iron field (steel of the vehicle magnetised by the earth's field) maps the horizontal field through a
symmetric matrix S = [[1 + e1, e2], [e2, 1 - e1]] (its mean scale, which turns nothing, taken out).  To first order
the compass then reads e1 sin 2A - e2 cos 2A off at raw angle A: a deviation of the second harmonic, zero on
average over the headings, 2-5 deg for e of 0.03-0.09 (US 4,734,863 FIG. 8A's deviation table holds it when the
compass was swung; the seeds do not learn it).  The filter of F-DELTA takes such an error for a wheel offset that
changes with every turn.

The wheels turn exactly (their own errors are a scale and an offset, not a function of the heading), so across a
turn DELTA = H_C - H_W changes by the deviation's change.  DELTA, s = sin 2A and c = cos 2A are high-passed by the
same exponential mean over SOFT_IRON_HIGHPASS_M metres (what is left of the slow offset, the coloured compass error
and the dip of hills is what changes faster than that), and the high-passed DELTA is regressed on the high-passed
(s, c) and, as a nuisance, the high-passed wheel turn (a wheel turn's scale error moves DELTA in every turn; in a
grid of streets the turns happen at few headings, and without it that error leaks into (p, q)).  Each sample is
weighted by the metres it drove times (clean sigma / its sigma)^2, the filter's own compass sigma (E_C, the lag in
turns), over samples the filter of F-DELTA took as clean (its clean weight above 1/2: anomalies, dropouts and
standstill teach nothing).  Since the deviation is linear in (s, c) its high-passed form is the same linear function
of the high-passed regressors, so the regression estimates (p, q) of DELTA's p s + q c directly, with a ridge prior
of SOFT_IRON_PRIOR_M metres of turning that says nothing (a drive that does not turn learns nothing).  The compass
heading is then read as H_C - (p s + q c), the amplitude soft-thresholded by SOFT_IRON_FLOOR.  The regression reads
the compass before this correction, so there is no loop.  Since stop 41 the compass it reads is already corrected by
the deviation read from the field's magnitude (jaxmodel/soft_iron_field.py): this learner regresses what is left.

Where it falls short: turns and grades fake a second harmonic of 0.1-0.8 deg on drives without a soft iron (a level
compass on a slope reads the grade times the dip, and the grade a road shows depends on its direction: (grad h . u)
sin psi holds sin 2 psi), hence the floor; and the ridge leaves 40-60 % of a real deviation unlearned after a 15-minute
drive (docs/tuning.md, stop 38).  Scenario matrix, tuning seeds 101-103: soft-iron drives 1.644 -> 1.521 deg
(geometric mean), no other condition moved by more than 0.005 deg; held-out 104-106: 1.137 -> 1.025 deg.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import wrap
from .packed import computed_once, packed_state

SOFT_IRON_HIGHPASS_M = 30.0
"""Metres of the exponential mean that DELTA, sin 2A and cos 2A are high-passed by (slower errors are the filter's)."""
SOFT_IRON_PRIOR_M = 100.0
"""Ridge prior of the regression (m of fully turned regressor): (p, q) move once turns outweigh it."""
SOFT_IRON_FLOOR = 0.01
"""Amplitude (rad, 0.57 deg) taken off the learned deviation's before it is applied (soft threshold).  Chosen on the
tuning seeds 101-103 with the prior (SOFT_IRON_PRIOR_M / floor: 100 m / 0 0.8677 deg, 100 m / 0.007 0.8467, 100 m /
0.01 0.8453, 200 m / 0.005 0.8456, 30 m / 0.015 0.8626, against 0.8491 without the learner)."""
SOFT_IRON_STEP = 0.2
"""A high-passed DELTA beyond this (rad, 11 deg) is a step, not a deviation: the means start again there."""
SOFT_IRON_MAX = 0.15
"""|p|, |q| at most this (rad, 8.6 deg): a deviation larger than that is not a soft iron."""


class SoftIronFields(NamedTuple):
    """mean_delta (rad), mean_s, mean_c: the high-pass's exponential means of DELTA, sin 2A, cos 2A; turn (rad): the
    wheels' turn high-passed the same way; n_ij (m): the normal matrix of the high-passed regressors (s, c, turn); b_i
    (rad m): its right-hand side; started: 1 once a clean sample set the means."""

    mean_delta: jnp.ndarray
    mean_s: jnp.ndarray
    mean_c: jnp.ndarray
    turn: jnp.ndarray
    n_ss: jnp.ndarray
    n_sc: jnp.ndarray
    n_st: jnp.ndarray
    n_cc: jnp.ndarray
    n_ct: jnp.ndarray
    n_tt: jnp.ndarray
    b_s: jnp.ndarray
    b_c: jnp.ndarray
    b_t: jnp.ndarray
    started: jnp.ndarray


SoftIronState = packed_state(SoftIronFields, "SoftIronState", "State of the online soft-iron deviation learner.")


def init_soft_iron_state() -> SoftIronState:
    return SoftIronState.pack(SoftIronFields(*([jnp.zeros((), jnp.float64)] * len(SoftIronFields._fields))))


def coefficients(ss):
    """(p, q) (rad): the deviation of DELTA as p sin 2A + q cos 2A, ridge-regressed beside the wheels' turn (whose
    coefficient, the wheel turn's scale error, is a nuisance here) and clipped to SOFT_IRON_MAX."""
    f = ss.fields()
    lam = SOFT_IRON_PRIOR_M
    a, b, c = f.n_ss + lam, f.n_sc, f.n_st
    d, e, g = f.n_cc + lam, f.n_ct, f.n_tt + lam
    # The symmetric 3x3 system by cofactors.
    c00, c01, c02 = d * g - e * e, c * e - b * g, b * e - c * d
    c11, c12 = a * g - c * c, b * c - a * e
    inv_det = 1.0 / (a * c00 + b * c01 + c * c02)
    p = (c00 * f.b_s + c01 * f.b_c + c02 * f.b_t) * inv_det
    q = (c01 * f.b_s + c11 * f.b_c + c12 * f.b_t) * inv_det
    return jnp.clip(p, -SOFT_IRON_MAX, SOFT_IRON_MAX), jnp.clip(q, -SOFT_IRON_MAX, SOFT_IRON_MAX)


def harmonics(heading):
    """(sin 2A, cos 2A) of the compass heading A (rad): the regressors, computed once per sample."""
    return jnp.sin(2.0 * heading), jnp.cos(2.0 * heading)


def deviation(ss, harmonics_of_a):
    """The learned deviation (rad) at a compass heading A given as ``harmonics(A)``: p sin 2A + q cos 2A with its
    amplitude soft-thresholded by SOFT_IRON_FLOOR; to subtract from H_C."""
    p, q = coefficients(ss)
    amp = jnp.sqrt(p * p + q * q + 1e-30)
    # Soft-thresholded: what turns and terrain fake on drives without a soft iron is not applied.
    keep = jnp.maximum(amp - SOFT_IRON_FLOOR, 0.0) / amp
    s, c = harmonics_of_a
    return keep * (p * s + q * c)


def update(ss, delta, harmonics_of_a, alpha, d_t, clean, quality):
    """One sample: ``delta`` = H_C - H_W before this module's correction (rad), ``harmonics_of_a`` those of the compass
    heading A it was read at (``harmonics``), ``alpha`` the wheels' turn this sample (rad), ``d_t`` the metres
    driven, ``clean`` (bool) the compass was taken as clean, ``quality`` (0, 1] the ratio of a clean compass's sigma
    to this sample's (E_C, the lag in turns).  Returns the state."""
    f = ss.fields()
    # A sample that is not clean may carry anything (a NaN compass): it must not reach the sums, not even times 0.
    delta = jnp.where(clean, delta, f.mean_delta)
    s, c = (jnp.where(clean, v, 0.0) for v in harmonics_of_a)
    r = wrap(delta - f.mean_delta)
    # A step of DELTA (a filter restarted from a compass, a shifted hard iron) starts the means again.
    first = computed_once(clean & ((f.started < 0.5) | (jnp.abs(r) > SOFT_IRON_STEP)))
    learn = clean & ~first & (d_t > 0.0)
    w = jnp.where(learn, d_t * quality ** 2, 0.0)
    xs, xc, xt = s - f.mean_s, c - f.mean_c, f.turn + alpha
    g = jnp.where(learn, 1.0 - jnp.exp(-d_t / SOFT_IRON_HIGHPASS_M), 0.0)
    new = SoftIronFields(
        mean_delta=jnp.where(first, delta, wrap(f.mean_delta + g * r)),
        mean_s=jnp.where(first, s, f.mean_s + g * xs),
        mean_c=jnp.where(first, c, f.mean_c + g * xc),
        turn=jnp.where(first, 0.0, (1.0 - g) * xt),
        n_ss=f.n_ss + w * xs * xs, n_sc=f.n_sc + w * xs * xc, n_st=f.n_st + w * xs * xt,
        n_cc=f.n_cc + w * xc * xc, n_ct=f.n_ct + w * xc * xt, n_tt=f.n_tt + w * xt * xt,
        b_s=f.b_s + w * xs * r, b_c=f.b_c + w * xc * r, b_t=f.b_t + w * xt * r,
        started=jnp.where(first, 1.0, f.started))
    return SoftIronState.pack(new)
