"""The compass's heading-dependent deviation (soft iron, and an offset's), learned online from the wheels' turns.

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

The first harmonic, p1 sin A + q1 cos A (stop 46), is regressed jointly with the second (x = (sin A, cos A, sin 2A,
cos 2A, turn), a 5 x 5 ridge solve written out for the native FMU).  A constant vector o added to the horizontal field
in the compass's frame turns the heading by |o| / B sin(A - angle of o): a hard iron the calibration left (X0, Y0 off
by 0.4 uT: about 1 deg), and a road's crossfall, which tips the vertical field into the lateral axis (a car leaning
1-2 % toward the kerb: 0.8-1.6 uT on 20 uT, 1.2 deg per % of crossfall, the same on every road of a drive).  Found
on the project's independent simulator (bench/independent_sim.py, docs/tuning.md stop 45): 0.5-4.3 deg on its drives,
the largest part of the compass's heading-dependent error there; our own simulator has neither.  The ridge and the
high-pass are the second harmonic's (a 300-m high-pass learned more of it but cost the matrix 0.837 -> 0.997 deg), so
a 15-minute drive learns a third to a half of it; the floor FIRST_HARMONIC_FLOOR is chosen in its docstring.

Where it falls short: turns and grades fake a second harmonic of 0.1-0.8 deg on drives without a soft iron (a level
compass on a slope reads the grade times the dip, and the grade a road shows depends on its direction: (grad h . u)
sin psi holds sin 2 psi), hence the floor; and the ridge leaves 40-60 % of a real deviation unlearned after a 15-minute
drive (docs/tuning.md, stop 38).  Scenario matrix, tuning seeds 101-103: soft-iron drives 1.644 -> 1.521 deg
(geometric mean), no other condition moved by more than 0.005 deg; held-out 104-106: 1.137 -> 1.025 deg.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from . import normal_equations as _ne
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
FIRST_HARMONIC_FLOOR = 0.005
"""Amplitude (rad, 0.29 deg) taken off the learned first harmonic's before it is applied (soft threshold).  Chosen on
the independent simulator's diagnosis seeds 1-4 (16 drives, geometric mean: not applied 1.472 deg; floor 0.02 / 0.01 /
0.005: 1.472 / 1.457 / 1.432) against the matrix's tuning seeds 101-103 (0.8374 -> 0.8438 deg at 0.005: our
simulator has no first harmonic, and turns fake one; highway/mismatch_1.5/102 +0.17 deg the worst).  Judged on
independent seeds 5-8: 1.480 -> 1.460 deg (urban 7 1.39 -> 1.27, urban 8 1.30 -> 1.20, highway 8 2.69 -> 2.56;
none worse by more than 0.03)."""

_K = 5  # regressors: sin A, cos A, sin 2A, cos 2A, the wheels' turn


SoftIronFields = NamedTuple("SoftIronFields", [(name, jnp.ndarray) for name in (
    "mean_delta", "mean_s1", "mean_c1", "mean_s", "mean_c", "turn", *_ne.sum_fields(_K), "started")])
SoftIronFields.__doc__ = """mean_delta (rad), mean_s1, mean_c1, mean_s, mean_c: the high-pass's exponential means
of DELTA, sin A, cos A, sin 2A, cos 2A; turn (rad): the wheels' turn high-passed the same way; n_ij (m), b_i
(rad m): the normal equations of the high-passed regressors x = (sin A, cos A, sin 2A, cos 2A, turn)
(jaxmodel/normal_equations.py); started: 1 once a clean sample set the means."""


SoftIronState = packed_state(SoftIronFields, "SoftIronState", "State of the online soft-iron deviation learner.")


def init_soft_iron_state() -> SoftIronState:
    return SoftIronState.pack(SoftIronFields(*([jnp.zeros((), jnp.float64)] * len(SoftIronFields._fields))))


def all_coefficients(ss):
    """(p1, q1, p, q) (rad): DELTA's deviation as p1 sin A + q1 cos A + p sin 2A + q cos 2A, ridge-regressed beside
    the wheels' turn (whose coefficient, the wheel turn's scale error, is a nuisance here), clipped to
    SOFT_IRON_MAX."""
    c = _ne.cholesky_solve(_ne.normal_matrix(ss.fields(), _K, [SOFT_IRON_PRIOR_M] * _K),
                           [getattr(ss, f"b{i}") for i in range(_K)])[0]
    return tuple(jnp.clip(v, -SOFT_IRON_MAX, SOFT_IRON_MAX) for v in c[:4])


def coefficients(ss):
    """(p, q) (rad): the second harmonic's, p sin 2A + q cos 2A (``all_coefficients``)."""
    return all_coefficients(ss)[2:]


def harmonics(heading):
    """(sin A, cos A, sin 2A, cos 2A) of the compass heading A (rad): the regressors, computed once per sample
    (jaxmodel/soft_iron_field.py reads the last two)."""
    s1, c1 = jnp.sin(heading), jnp.cos(heading)
    return s1, c1, 2.0 * s1 * c1, c1 * c1 - s1 * s1


def _soft_threshold(p, q, floor):
    amp = jnp.sqrt(p * p + q * q + 1e-30)
    return jnp.maximum(amp - floor, 0.0) / amp


def deviation(ss, harmonics_of_a):
    """The learned deviation (rad) at a compass heading A given as ``harmonics(A)``: p1 sin A + q1 cos A + p sin 2A
    + q cos 2A, each harmonic's amplitude soft-thresholded (FIRST_HARMONIC_FLOOR, SOFT_IRON_FLOOR); to subtract
    from H_C."""
    p1, q1, p, q = all_coefficients(ss)
    s1, c1, s, c = harmonics_of_a
    # Soft-thresholded: what turns and terrain fake on drives without a soft iron is not applied.
    return (_soft_threshold(p, q, SOFT_IRON_FLOOR) * (p * s + q * c)
            + _soft_threshold(p1, q1, FIRST_HARMONIC_FLOOR) * (p1 * s1 + q1 * c1))


def update(ss, delta, harmonics_of_a, alpha, d_t, clean, quality):
    """One sample: ``delta`` = H_C - H_W before this module's correction (rad), ``harmonics_of_a`` those of the compass
    heading A it was read at (``harmonics``), ``alpha`` the wheels' turn this sample (rad), ``d_t`` the metres
    driven, ``clean`` (bool) the compass was taken as clean, ``quality`` (0, 1] the ratio of a clean compass's sigma
    to this sample's (E_C, the lag in turns).  Returns the state."""
    f = ss.fields()
    # A sample that is not clean may carry anything (a NaN compass): it must not reach the sums, not even times 0.
    delta = jnp.where(clean, delta, f.mean_delta)
    h = [jnp.where(clean, v, 0.0) for v in harmonics_of_a]
    r = wrap(delta - f.mean_delta)
    # A step of DELTA (a filter restarted from a compass, a shifted hard iron) starts the means again.
    first = computed_once(clean & ((f.started < 0.5) | (jnp.abs(r) > SOFT_IRON_STEP)))
    learn = clean & ~first & (d_t > 0.0)
    w = jnp.where(learn, d_t * quality ** 2, 0.0)
    means = (f.mean_s1, f.mean_c1, f.mean_s, f.mean_c)
    x = [v - m for v, m in zip(h, means)] + [f.turn + alpha]
    g = jnp.where(learn, 1.0 - jnp.exp(-d_t / SOFT_IRON_HIGHPASS_M), 0.0)
    new_means = [jnp.where(first, v, m + g * xi) for v, m, xi in zip(h, means, x)]
    sums = {f"n{i}{j}": getattr(f, f"n{i}{j}") + w * x[i] * x[j] for i, j in _ne.pairs(_K)}
    sums.update({f"b{i}": getattr(f, f"b{i}") + w * x[i] * r for i in range(_K)})
    new = SoftIronFields(
        mean_delta=jnp.where(first, delta, wrap(f.mean_delta + g * r)),
        mean_s1=new_means[0], mean_c1=new_means[1], mean_s=new_means[2], mean_c=new_means[3],
        turn=jnp.where(first, 0.0, (1.0 - g) * x[4]),
        started=jnp.where(first, 1.0, f.started), **sums)
    return SoftIronState.pack(new)
