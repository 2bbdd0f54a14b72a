"""The heading started from position fixes: the Kalman mode without a usable compass (SPEC §8).

SPEC §8: ``initialized`` stays 0 until a valid compass sample, or in the Kalman mode a fix, has set the heading.
US 4,680,715 corrects the course from fixes only through the position errors a small course error makes (its
error model is linear in dth2); it is silent on how fixes start a course nothing else has started.  Before this
module the Kalman mode waited for a compass that never came: with 1-Hz fixes of 4 m and no compass, the matrix's
no-compass drives were 5-130 deg off for their whole 15 minutes (the wheel heading started at 0 and the filter
never ran; stop 49).

The wheels know the track's shape, the fixes where it lies.  Until the heading is initialized, the wheels'
dead-reckoned track p_k (east, north; m) is integrated in the frame of the unstarted wheel heading H_W from the
first valid fix on, and the least-squares rotation of the centred track onto the centred fixes f_k - f_0 (2-D
Procrustes) is the wheel heading's missing offset:

    theta = atan2(sum(f_E p_N - f_N p_E), sum(f_E p_E + f_N p_N))        (p, f centred)

with residual sum |f - R p - t|^2 = S_ff + S_pp - 2 sqrt(S^2 + C^2) (S, C the two sums above) and standard deviation
sigma_theta^2 = (max(sigma_white, residual RMS)^2 + sigma_coloured^2 n / n_independent) / S_pp, S_pp the track's
spread (m^2; ``rotation``): turns only help.  The heading starts at H_W + theta once sigma_theta is within
ALIGN_SIGMA_DEG; the Kalman course starts with that variance and the position computer at that fix (kalman.align_after,
which also re-aligns a course that lost its fixes).  A residual RMS beyond ALIGN_RESTART_FACTOR fix sigmas (a fix
outlier, a wheel course drifting with a tyre mismatch) starts the sums again from the current fix.  Only the track's
shape enters, so the distance scale need not be known well (a 1 % scale error adds 1 % of the spread to the residual,
not to theta).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import safe_sqrt
from .packed import computed_once, packed_state
from .params import deg

ALIGN_SIGMA_DEG = 6.0
"""The rotation's standard deviation (deg) at which it starts the heading; the Kalman filter's course starts with
its variance (at least kf_heading_sigma0_deg's) and the fixes refine it.  Chosen on the matrix's no-compass drives of
the tuning seeds 101-103 (1.5 / 3 / 6 / 10 / 20 deg with the coloured term; RMSE after the first minute summed over
the 12 drives: parking never or late started at 1.5-3 deg, 8.58 deg at 6, 9.09 at 10, 8.62 at 20)."""
ALIGN_MIN_FIXES = 5.0
"""Fixes in the sums before the rotation is believed, whatever its sigma."""
ALIGN_RESTART_FACTOR = 4.0
"""Residual RMS (per axis, in fix sigmas) beyond which the sums start again from the current fix."""
MAX_FIX_M = 1.0e7
"""Fixes farther than this from the origin (m) are not plausible (kalman.MAX_FIX_M is this)."""


class AlignmentFields(NamedTuple):
    started: jnp.ndarray  # 1.0 once a fix started the sums
    p_east: jnp.ndarray   # wheels' track since that fix, in the unstarted H_W's frame (m)
    p_north: jnp.ndarray
    f0_east: jnp.ndarray  # that fix (m)
    f0_north: jnp.ndarray
    n: jnp.ndarray        # fixes in the sums
    elapsed: jnp.ndarray  # time since the first of them (s)
    sum_pe: jnp.ndarray   # sums over the fixes of p, f - f0 (m), their dot and cross products and squares (m^2)
    sum_pn: jnp.ndarray
    sum_fe: jnp.ndarray
    sum_fn: jnp.ndarray
    sum_dot: jnp.ndarray
    sum_cross: jnp.ndarray
    sum_pp: jnp.ndarray
    sum_ff: jnp.ndarray
    frozen_drift: jnp.ndarray  # while re-aligning: the Kalman's dth2^ when it lost the fixes, run on by its beta (rad)
    frozen_rate: jnp.ndarray   # ... and that beta^ (rad/m)
    by_fixes: jnp.ndarray    # 1.0 once the fixes started the heading (no compass had)
    realigning: jnp.ndarray  # 1.0 while the sums run again on the Kalman course as it was, after it lost the fixes


AlignmentState = packed_state(AlignmentFields, "AlignmentState",
                              "Sums of the wheels' track against the fixes before the heading is started.")
_FROZEN_DRIFT, _BY_FIXES, _REALIGNING = (AlignmentFields._fields.index(f)
                                         for f in ("frozen_drift", "by_fixes", "realigning"))


def init_alignment_state():
    z = jnp.zeros((), jnp.float64)
    return AlignmentState.pack(AlignmentFields(*([z] * len(AlignmentFields._fields))))


def fix_sigma(params):
    """Per-axis sigma (m) of a fix: white and coloured parts (kf_fix_sigma_m, kf_fix_gm_sigma_m)."""
    return jnp.sqrt(params.kf_fix_sigma_m ** 2 + params.kf_fix_gm_sigma_m ** 2)


def rotation(a: AlignmentFields, sigma_white, sigma_coloured, tau_coloured):
    """(theta (rad), its sigma (rad), residual RMS per axis (m)) of the fixes' sums; sigma inf while undetermined.

    The white part of the fix errors (at least the residual RMS) averages over the n fixes: sigma / sqrt(S_pp).  The
    coloured part (correlated over tau_coloured s) averages only over the independent stretches of 2 tau in the
    fixes' time (at least one): a short drive's fixes carry one coloured error however many there are."""
    n = jnp.maximum(a.n, 1.0)
    s_pp = a.sum_pp - (a.sum_pe ** 2 + a.sum_pn ** 2) / n
    s_ff = a.sum_ff - (a.sum_fe ** 2 + a.sum_fn ** 2) / n
    s = a.sum_dot - (a.sum_pe * a.sum_fe + a.sum_pn * a.sum_fn) / n
    c = a.sum_cross - (a.sum_fe * a.sum_pn - a.sum_fn * a.sum_pe) / n
    # Double where: at s = c = 0 (one fix, a vehicle standing) arctan2's gradient is 0/0.
    degenerate = (s == 0.0) & (c == 0.0)
    theta = jnp.where(degenerate, 0.0, jnp.arctan2(c, jnp.where(degenerate, 1.0, s)))
    residual = jnp.maximum(s_ff + s_pp - 2.0 * safe_sqrt(s * s + c * c), 0.0)
    rms = safe_sqrt(residual / jnp.maximum(2.0 * n - 3.0, 1.0))
    determined = (a.n >= 2.0) & (s_pp > 0.0)
    spread = jnp.where(determined, s_pp, 1.0)
    independent = jnp.clip(a.elapsed / jnp.maximum(2.0 * tau_coloured, 1e-9), 1.0, n)
    variance = (jnp.maximum(sigma_white, rms) ** 2 + sigma_coloured ** 2 * n / independent) / spread
    sigma = jnp.where(determined, safe_sqrt(variance), jnp.inf)
    return theta, sigma, rms


def update(params, al, *, dt, distance, course, fix_east, fix_north, fix_valid, waiting):
    """One sample; returns (new AlignmentState, aligned (bool), theta (rad), its sigma (rad)).

    dt: the sample's time step (s, 0 when unusable); distance: its signed travel AD (m); course: the unstarted
    wheel heading at mid-sample (rad);
    waiting: the heading has not been started (the sums run only then, and freeze after).  ``aligned``: this
    sample's fix determined theta within ALIGN_SIGMA_DEG; the heading is then H_W + theta.  theta and its sigma are
    those of the sums with this sample's fix: meaningful on a sample with a valid fix only.
    """
    a = al.fields()
    fix_ok = computed_once(waiting & (fix_valid > 0.5) & (jnp.abs(fix_east) < MAX_FIX_M)
                           & (jnp.abs(fix_north) < MAX_FIX_M))  # also false for NaN/inf
    moved = waiting & (a.started > 0.5) & jnp.isfinite(distance) & jnp.isfinite(course)
    pe = a.p_east + jnp.where(moved, distance * jnp.sin(course), 0.0)
    pn = a.p_north + jnp.where(moved, distance * jnp.cos(course), 0.0)
    fe = jnp.where(fix_ok, fix_east, 0.0) - a.f0_east
    fn = jnp.where(fix_ok, fix_north, 0.0) - a.f0_north
    elapsed = a.elapsed + jnp.where(waiting & (a.started > 0.5) & jnp.isfinite(dt), jnp.clip(dt, 0.0, 60.0), 0.0)
    grown = AlignmentFields(a.started, pe, pn, a.f0_east, a.f0_north, a.n + 1.0, elapsed, a.sum_pe + pe, a.sum_pn + pn,
                            a.sum_fe + fe, a.sum_fn + fn, a.sum_dot + fe * pe + fn * pn,
                            a.sum_cross + fe * pn - fn * pe, a.sum_pp + pe * pe + pn * pn, a.sum_ff + fe * fe + fn * fn,
                            *_carried(a))
    sigma_fix = fix_sigma(params)
    theta, sigma, rms = rotation(grown, params.kf_fix_sigma_m, params.kf_fix_gm_sigma_m, params.kf_fix_gm_tau_s)
    inconsistent = (grown.n >= ALIGN_MIN_FIXES) & (rms > ALIGN_RESTART_FACTOR * sigma_fix)
    settled = (grown.n >= ALIGN_MIN_FIXES) & (sigma <= deg(ALIGN_SIGMA_DEG))
    aligned = fix_ok & (a.started > 0.5) & settled & ~inconsistent
    z = jnp.zeros_like(pe)
    one = jnp.ones_like(pe)
    # The first fix, or one after an inconsistent stretch: the sums start again with it (p = 0, f - f0 = 0).
    first = AlignmentFields(one, z, z, jnp.where(fix_ok, fix_east, 0.0), jnp.where(fix_ok, fix_north, 0.0), one,
                            z, z, z, z, z, z, z, z, z, *_carried(a))
    restart = computed_once(fix_ok & ((a.started < 0.5) | inconsistent))
    take = computed_once(fix_ok)
    moved_only = a._replace(p_east=pe, p_north=pn, elapsed=elapsed)
    new = jnp.where(restart, AlignmentState.pack(first).vector,
                    jnp.where(take, AlignmentState.pack(grown).vector, AlignmentState.pack(moved_only).vector))
    return AlignmentState(new), aligned, theta, sigma


def _carried(a):
    """The fields the sums do not touch (from frozen_drift on)."""
    return a.frozen_drift, a.frozen_rate, a.by_fixes, a.realigning


def again(al, drift, rate):
    """The sums emptied to run again (``realigning``) on the Kalman course as it was when it lost the fixes: its
    dth2^ ``drift`` (rad) run on by its beta^ ``rate`` (rad/m), frozen (kalman.align_after)."""
    z = jnp.zeros_like(al.vector[..., 0])
    fields = AlignmentFields(*([z] * (len(AlignmentFields._fields) - 4)), z + drift, z + rate, z + 1.0, z + 1.0)
    return AlignmentState.pack(fields)


def run_frozen(al, distance):
    """The frozen dth2^ moved on by its beta^ over the sample's signed travel (m), while re-aligning."""
    a = al.fields()
    moved = jnp.where(a.realigning > 0.5, a.frozen_rate * distance, 0.0)
    return AlignmentState(al.vector.at[..., _FROZEN_DRIFT].add(moved))


def done(al, where, by_fixes=1.0):
    """``al`` with no re-alignment running and ``by_fixes`` set as given where ``where``: 1 where this sample's fix
    started or re-aligned the course, 0 where a valid compass ended the fixes' hold on it."""
    ended = al.vector.at[..., _BY_FIXES].set(by_fixes).at[..., _REALIGNING].set(0.0)
    return AlignmentState(jnp.where(where, ended, al.vector))
