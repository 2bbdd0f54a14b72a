"""Identification against position fixes (issue 14): the loss on displacements over windows of fixes.

Most vehicles log a GNSS receiver, not a dense reference heading.  A single fix says nothing about
the heading, and the dead-reckoned position carries an unknown start (its origin, and for the
odometer heading an unknown start heading too), so the track is compared with the fixes through
*displacements over windows of fixes* (chords):

    for each fix k, its partner j = the last fix at least ``window_s`` earlier (both ends valid);
    d_k     = fix_k - fix_j                                          (east, north; m)
    m_k     = (x_k - x_j, y_k - y_j)                                 (the dead-reckoned chord, same samples)
    e_k     = wrap(atan2(m_k) - atan2(d_k))                          (course of the chord, clockwise from north)

The chord's direction does not depend on where the track started nor on its distance scale, and
in a turn both chords cut the same arc, so e_k is exact whatever the vehicle does between the two
fixes (unlike the course over ground taken as a heading, which lags in turns).  The position of
the track comes from the estimator's own dead reckoning (``jaxmodel.step``: x += AD sin(psi_mid),
y += AD cos(psi_mid), with psi the heading of the mode), so e_k carries the heading of that mode
averaged along the chord.

Weights, by the accuracy of each chord's course: with fix errors sigma_f per axis the course of
d_k has a variance of about 2 sigma_f² / |d_k|²; the dead-reckoned chord adds its own heading error,
a floor sigma_h², so

    w_k = 1 / (2 sigma_f² / |d_k|² + sigma_h²)                       (rad⁻²; chords shorter than min_dist_m: 0)

and the residual is r_k = 2 sin(e_k / 2) (r² = 2 (1 - cos e), as the heading loss, SPEC §1).  The
data term is the heading loss's (``loss.data_term``): sum_d (n_d/2) log(S_d/W_d) with each drive's
error level profiled out, so sigma_f and sigma_h only shape the relative weights within a drive.

Unknown start heading: the odometer heading starts from one compass sample (a constant offset of
the whole drive), so the wheel stage fits *changes* of the chord error: r = 2 sin((e_k - e_p)/2)
with p the last chord ending at least ``increment_s`` (60 s) earlier, weighted 1/(1/w_k + 1/w_p) (the
variances add).  The offset cancels exactly, as in the heading loss's increments.  Stages on an
absolute heading (compass, complementary, Kalman) fit e_k itself: the offset is what they must
remove, and the fixes, unlike the compass, know true north.

n_d, the effective number of independent errors, is the drive's span covered by chords divided by
the window (or the increment for changes): overlapping chords are far from independent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxmodel.angles import wrap

from . import loss as L

DEFAULT_WINDOW_S = 20.0
"""Chord length in time: long enough that the fixes' noise is small against the displacement at
town speeds (20 s at 10 m/s: 200 m, 1.2° for sigma_f = 3 m), short enough for many chords
(measured against 5, 10 and 30 s: docs/identification.md)."""
DEFAULT_INCREMENT_S = 60.0
"""The wheel stage fits changes of the chord error over this span (measured against 30 and 90 s)."""
DEFAULT_FIX_SIGMA_M = 3.0
"""Assumed fix error per axis (m) in the chord weights (only their relative size matters)."""
DEFAULT_HEADING_FLOOR_DEG = 1.0
"""Assumed heading error of the dead-reckoned chord itself (weights of long chords)."""
DEFAULT_MIN_DIST_M = 10.0
"""Chords shorter than this carry no usable course (standstill, parking at walking pace)."""
DEFAULT_STRAIGHT_DEG = 10.0
"""Compass stage: only chords over which the odometer heading turns less than this.  In a turn the
body rolls (lateral acceleration) and the vertical field leaks into the horizontal components (the
dip or turning error); a deviation curve fitted there absorbs the turns of the training drives
(measured: docs/identification.md)."""
MAX_WINDOW_FACTOR = 3.0
"""A chord spanning more than this many windows (across a fix outage) is not used."""


@dataclass(frozen=True)
class FixSettings:
    window_s: float = DEFAULT_WINDOW_S
    increment_s: float = DEFAULT_INCREMENT_S
    fix_sigma_m: float = DEFAULT_FIX_SIGMA_M
    heading_floor_deg: float = DEFAULT_HEADING_FLOOR_DEG
    min_dist_m: float = DEFAULT_MIN_DIST_M
    straight_deg: float = DEFAULT_STRAIGHT_DEG


@dataclass
class Chords:
    """Chords of every drive of a batch, padded to the same count K: arrays (batch, K)."""

    end: np.ndarray       # sample index of the later fix
    start: np.ndarray     # sample index of the earlier fix
    d_east: np.ndarray    # fix displacement, m
    d_north: np.ndarray
    weight: np.ndarray    # w_k (0 on padding and short chords)
    time_s: np.ndarray    # time of the later fix
    n_fixes: np.ndarray   # (batch,) valid fixes per drive

    @property
    def count(self) -> np.ndarray:
        return np.sum(self.weight > 0, axis=-1)


def has_fixes(drive, minimum: int = 2) -> bool:
    """True when the drive has at least ``minimum`` valid fixes."""
    return int(np.count_nonzero(np.asarray(drive.inputs.fix_valid) > 0.5)) >= minimum


def make_chords(inputs, mask, settings: FixSettings = FixSettings()) -> Chords:
    """The chords of a stacked batch (numpy; ``inputs`` as from ``drive_log.stack_drives``)."""
    t_all = np.asarray(inputs.time_s, dtype=np.float64)
    valid_all = (np.asarray(inputs.fix_valid) > 0.5) & (np.asarray(mask) > 0.5)
    per = []
    n_fixes = []
    var_h = math.radians(settings.heading_floor_deg) ** 2
    for b in range(t_all.shape[0]):
        idx = np.flatnonzero(valid_all[b])
        n_fixes.append(idx.size)
        if idx.size < 2:
            per.append([np.zeros(0, np.int64)] * 2 + [np.zeros(0)] * 4)
            continue
        t = t_all[b, idx]
        e = np.asarray(inputs.fix_east_m[b], dtype=np.float64)[idx]
        n = np.asarray(inputs.fix_north_m[b], dtype=np.float64)[idx]
        j = np.searchsorted(t, t - settings.window_s, side="right") - 1
        ok = (j >= 0)
        jj = np.clip(j, 0, None)
        ok &= (t - t[jj]) <= MAX_WINDOW_FACTOR * settings.window_s
        de, dn = e - e[jj], n - n[jj]
        dist2 = de * de + dn * dn
        ok &= dist2 >= settings.min_dist_m ** 2
        w = np.where(ok, 1.0 / (2.0 * settings.fix_sigma_m ** 2 / np.where(ok, dist2, 1.0) + var_h), 0.0)
        keep = np.flatnonzero(ok)
        per.append([idx[keep], idx[jj[keep]], de[keep], dn[keep], w[keep], t[keep]])
    k_max = max(1, max(len(p[0]) for p in per))

    def pad(i, dtype):
        out = np.zeros((len(per), k_max), dtype=dtype)
        for b, p in enumerate(per):
            out[b, :len(p[i])] = p[i]
        return out

    return Chords(pad(0, np.int64), pad(1, np.int64), pad(2, np.float64), pad(3, np.float64), pad(4, np.float64),
                  pad(5, np.float64), np.asarray(n_fixes))


def chord_increment_index(chords: Chords, increment_s: float) -> np.ndarray:
    """For each chord the last chord (same drive) ending at least ``increment_s`` earlier, -1 if none."""
    out = np.full(chords.end.shape, -1, dtype=np.int64)
    for b in range(chords.end.shape[0]):
        n = int(np.count_nonzero(chords.weight[b] > 0))
        t = chords.time_s[b, :n]
        out[b, :n] = np.searchsorted(t, t - increment_s, side="right") - 1
    return out


def chord_errors(x, y, started, chords: Chords):
    """(e, w): the wrapped course errors of the dead-reckoned chords (batch, K) and their weights
    (zero where either end precedes the start of the heading); no gradient flows through w."""
    end = jnp.asarray(chords.end)
    start = jnp.asarray(chords.start)
    take = lambda a, i: jnp.take_along_axis(a, i, axis=-1)  # noqa: E731
    mx = take(x, end) - take(x, start)
    my = take(y, end) - take(y, start)
    course_fix = np.arctan2(chords.d_east, chords.d_north)
    # the model's chord can be (near) zero only where the weight is 0 anyway; keep atan2's gradient finite
    ok = (mx * mx + my * my) > 1e-12
    course = jnp.arctan2(jnp.where(ok, mx, 1.0), jnp.where(ok, my, 0.0))
    e = wrap(course - jnp.asarray(course_fix))
    both = (take(started, end) > 0.5) & (take(started, start) > 0.5) & ok
    w = jax.lax.stop_gradient(jnp.asarray(chords.weight) * both)
    return e, w


def chord_residuals(e, w, prev=None, align: bool = False):
    """(r, w'): r = 2 sin(e'/2) with e' = e, or its change since chord ``prev`` (variances added),
    or e minus its per-drive weighted circular mean (``align``)."""
    if prev is not None:
        prev = jnp.asarray(prev)
        idx = jnp.clip(prev, 0, None)
        e_p = jnp.take_along_axis(e, idx, axis=-1)
        w_p = jnp.take_along_axis(w, idx, axis=-1)
        ok = (prev >= 0) & (w > 0) & (w_p > 0)
        w2 = jnp.where(ok, w * w_p / jnp.where(ok, w + w_p, 1.0), 0.0)
        return 2.0 * jnp.sin(0.5 * wrap(e - e_p)), w2
    return L.residuals(e, w, align)


def effective_chord_counts(chords: Chords, span_s: float) -> np.ndarray:
    """n_d: the time covered by usable chords over ``span_s`` (the window or the increment), at least 1."""
    out = np.zeros(chords.end.shape[0])
    for b in range(out.size):
        t = chords.time_s[b][chords.weight[b] > 0]
        if t.size:
            gaps = np.diff(t)
            covered = float(np.sum(np.minimum(gaps, 2.0 * np.median(gaps)))) if gaps.size else 0.0
            out[b] = max(covered / float(span_s), 1.0)
    return out


@dataclass
class FixesProblem:
    """One fitting stage against the fixes; the same interface as ``loss.StageProblem``
    (``space``, ``n_eff``, ``objective``, ``residual_fn``), so the optimiser and the forward-mode
    derivatives of ``loss.forward_value_grad_gn`` apply unchanged."""

    space: L.ParamSpace
    base: object
    inputs: object
    chords: Chords
    config: object
    n_eff: np.ndarray
    prev: np.ndarray | None = None   # chord increments (wheel stage)
    align: bool = False
    straight_deg: float = 0.0        # > 0: only chords over which the odometer heading turns less (compass stage)

    def _r(self, z, checkpoint=False):
        p = self.space.to_params(z, self.base)
        x, y, wh, started = L.batch_outputs(p, self.inputs, self.config, ("x", "y", "wheel_heading"), checkpoint)
        e, w = chord_errors(x, y, started, self.chords)
        if self.straight_deg > 0:
            turn = wrap(jnp.take_along_axis(wh, jnp.asarray(self.chords.end), axis=-1)
                        - jnp.take_along_axis(wh, jnp.asarray(self.chords.start), axis=-1))
            w = w * jax.lax.stop_gradient(jnp.abs(turn) < math.radians(self.straight_deg))
        r, w = chord_residuals(e, w, self.prev, self.align)
        return r, w, e

    def objective(self, z, checkpoint: bool = False):
        r, w, _ = self._r(z, checkpoint)
        return L.data_term(r, w, jnp.asarray(self.n_eff)) + 0.5 * jnp.sum(z * z)

    def residual_fn(self, z):
        r, w, e = self._r(z)
        return r, (w, e)


def build_problem(space, base, inputs, mask, config, *, absolute: bool, increment_s: float,
                  settings: FixSettings = FixSettings(), align: bool = False,
                  straight: bool = False) -> FixesProblem:
    """The fixes stage problem: chord changes over ``increment_s`` (``absolute`` False, the odometer
    heading), or absolute chord errors (``absolute``); ``straight``: straight chords only."""
    chords = make_chords(inputs, mask, settings)
    prev = None
    if not absolute and not align and increment_s > 0:
        prev = chord_increment_index(chords, increment_s)
        n_eff = effective_chord_counts(chords, max(increment_s, settings.window_s))
    else:
        n_eff = effective_chord_counts(chords, settings.window_s)
    return FixesProblem(space, base, inputs, chords, config, n_eff, prev, align and not absolute,
                        settings.straight_deg if straight else 0.0)


# ----------------------------------------------------------------------------------------------
# evaluation against fixes (report, real data)


def chord_course_rmse_deg(x, y, started, chords: Chords, b: int, min_dist_m: float = 20.0) -> float:
    """RMS (deg) of the course error of drive b's dead-reckoned chords at least ``min_dist_m`` long
    (unweighted: how a user reads it)."""
    x, y, started = (np.asarray(a)[b:b + 1] for a in (x, y, started))
    sub = Chords(*(np.asarray(getattr(chords, f))[b:b + 1] for f in ("end", "start", "d_east", "d_north", "weight",
                                                                        "time_s")), chords.n_fixes[b:b + 1])
    e, w = chord_errors(jnp.asarray(x), jnp.asarray(y), jnp.asarray(started), sub)
    e, w = np.asarray(e)[0], np.asarray(w)[0]
    keep = (w > 0) & (np.hypot(sub.d_east[0], sub.d_north[0]) >= min_dist_m)
    if not np.any(keep):
        return float("nan")
    return float(np.degrees(np.sqrt(np.mean(e[keep] ** 2))))


def position_rmse_m(x, y, fix_east, fix_north, fix_valid, started, align_fixes: int = 5) -> float:
    """RMS (m) distance of the dead-reckoned track from the fixes, the track translated so that it
    matches the mean of its first ``align_fixes`` fixes after the heading started (one drive, numpy);
    ``align_fixes`` = 0: not translated (a track already in the fixes' frame, the Kalman mode's), the
    first fix left out (it initialises that track)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    ok = (np.asarray(fix_valid) > 0.5) & (np.asarray(started) > 0.5)
    idx = np.flatnonzero(ok)
    if idx.size < 2:
        return float("nan")
    if align_fixes > 0:
        first = idx[:align_fixes]
        ox = np.mean(np.asarray(fix_east)[first] - x[first])
        oy = np.mean(np.asarray(fix_north)[first] - y[first])
    else:
        ox = oy = 0.0
        idx = idx[1:]
    dx = x[idx] + ox - np.asarray(fix_east)[idx]
    dy = y[idx] + oy - np.asarray(fix_north)[idx]
    return float(np.sqrt(np.mean(dx * dx + dy * dy)))
