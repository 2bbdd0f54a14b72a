"""The wheels' distance per pulse found from the drive's own compass, where the parameter file does not give it.

Without the vehicle's parameters the estimator runs the nominal vehicle (``jaxmodel.for_unidentified_vehicle``),
whose distance per pulse may be far from the vehicle's: another simulator's vehicles had 0.017-0.052 m against the
nominal 0.02, and tyres 0-1.5 % apart, so the nominal wheels turned 130 deg in a minute of straight road and read a
96 deg turn as 44 (docs/tuning.md, stops 80-81).  The turn scale state learns a few per cent online; a factor of two
it does not.

Over windows of ``window_s`` seconds the change of the compass heading H_C (US 4,734,863 FIG. 8A, the model's own
compass mode) is the wheels' turn, US 4,788,645 eq. (8), with the counts N_L, N_R of the window:

    dH_C = (dpp_left N_L - dpp_right N_R) / T_E(0)                                      (1)

linear in (dpp_left, dpp_right).  A straight window pins their ratio (the compass does not turn), a turn their
scale.  Solved by iteratively reweighted least squares with Huber weights (a window inside a magnetic anomaly is an
outlier of (1), not a turn); windows whose ends have a compass sample the model rejected, or that hold an
odometer sample it found implausible, a burst, or a gap in time, are left out (a glitch is a leverage point no
weight in dH_C can hold).  The counts are divided by eq. (8)'s 1 + a V^2.  T_E(0) is eq. (14) at zero curvature,
T_F (T_R for sensors on the rear axle), the file's track (the nominal's where it gives none), so the distance per pulse found is the vehicle's only as
far as its track is that one (the nominal's within ~10 % on another simulator's vehicles; the heading needs only
the ratio dpp / T_E).

This uses the whole drive (``odocompass estimate`` post-processes a log); it is not a filter.  It runs wherever the
file gives neither dpp (``dpp_unknown``): also a file with the vehicle's geometry from its data sheet but no measured
pulse scale (independent simulator, diagnosis drives: 14.6 deg with the nominal 0.02 m, 2.6 with the fit, 1.8 with
the turn-scale state too).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WINDOW_S = 10.0
"""Window (s): short enough that the compass heading's change is within +-180 deg, long enough for whole pulses."""
MIN_WINDOW_PULSES = 20.0
"""A window with fewer counts of both wheels together is standing still: left out."""
MIN_WINDOWS = 30
"""Fewer usable windows than this (5 minutes at 10 s): no fit (the nominal vehicle stays)."""
MIN_TURN_DEG = 360.0
"""The windows must turn at least this much in all (sum of |dH_C|): a straight drive fixes the ratio, not the
scale."""
MAX_SCALE_SE = 0.05
"""Relative standard error of the scale above which the fit is not used."""
MAX_RATIO = 0.1
"""Tyres fitted more than this apart (|dpp_right / dpp_left - 1|) are no tyres: no fit."""
DPP_RANGE = (0.2, 5.0)
"""The distance per pulse found must lie within these factors of the nominal's, else it is not used."""
EQUAL_TYRES = 1e-3
"""A fitted ratio dpp_right / dpp_left within this of 1 is taken as 1 (both wheels their mean): the fit's ratio is
good to ~1e-4, and a ratio 1e-4 off drifts the wheel heading 27 deg over a 5-minute compass dropout at 90 km/h
(matrix mixed/dropouts/106: 3.4 -> 15.0 deg); the online calibration (EP 0619873) finds the rest.  Nominal vehicle,
matrix seeds 101-103 / 104-106 / independent simulator: 1.181 / 1.617 / 2.343 deg without, 1.067 / 1.260 / 2.320
with it (docs/tuning.md, stop 81)."""
_HUBER_K = 2.0
_IRLS_ITERATIONS = 20


@dataclass(frozen=True)
class WheelScales:
    """Distance per pulse of each wheel (m), from ``n_windows`` windows; ``scale_se`` the relative standard error of
    their mean, ``residual_deg`` the robust sigma of (1)'s residual."""

    dpp_left: float
    dpp_right: float
    n_windows: int
    scale_se: float
    residual_deg: float


def _counts(counter: np.ndarray, modulus: float, expected: np.ndarray) -> np.ndarray:
    """Per-sample increments of a wrapping counter, each the one within modulus/2 of ``expected`` (pulses), decoded
    by the model's own jaxmodel.odometer.decode_counter (an 8-bit counter at 1 Hz wraps more than half its modulus
    between samples above ~2.5 m/s)."""
    from jaxmodel.odometer import decode_counter

    return np.concatenate([[0.0], np.asarray(decode_counter(counter[1:], counter[:-1], modulus, expected[1:]))])


def _huber_fit(a: np.ndarray, y: np.ndarray):
    """Huber IRLS of y ~ a @ x: (x, robust sigma of the residual, covariance of x), or None where ``a`` cannot
    tell its two unknowns apart (a wheel that never counts, one counter copied into the other)."""
    if np.linalg.matrix_rank(a) < a.shape[1]:
        return None
    w = np.ones_like(y)
    for _ in range(_IRLS_ITERATIONS):
        sw = np.sqrt(w)
        x, *_ = np.linalg.lstsq(a * sw[:, None], y * sw, rcond=None)
        r = np.abs(y - a @ x)
        sigma = 1.4826 * np.median(r) + 1e-6
        c = _HUBER_K * sigma
        w = c / np.maximum(r, c)
    try:
        cov = sigma ** 2 * np.linalg.inv((a * w[:, None]).T @ a)
    except np.linalg.LinAlgError:
        return None
    return x, sigma, cov


def fit(params, drive, compass_heading: np.ndarray, compass_ok: np.ndarray, odometer_ok: np.ndarray,
        speed: np.ndarray | None = None, window_s: float = WINDOW_S) -> WheelScales | None:
    """(1) fitted on one drive: ``compass_heading`` H_C (rad, (N,)), ``compass_ok`` / ``odometer_ok`` the model's
    compass_valid / odometer_valid (N,), ``speed`` its speed with ``params``' dpp (m/s, (N,); None: standing
    still), which decodes the counters' wraps and gives eq. (8)'s velocity term 1 + a V^2 (the counts of each sample
    divided by it, V rescaled by the fitted dpp, twice).  None where the drive cannot tell (too short, too straight,
    no compass, a dead wheel, a fit too uncertain, tyres more than MAX_RATIO apart or outside DPP_RANGE)."""
    inputs = drive.inputs
    t = np.asarray(inputs.time_s, np.float64)
    if t.size < 3:
        return None
    nominal = 0.5 * (float(params.dpp_left) + float(params.dpp_right))
    speed = np.zeros_like(t) if speed is None else np.nan_to_num(np.asarray(speed, np.float64))
    expected = speed * np.concatenate([[0.0], np.diff(t)]) / nominal
    modulus = float(params.counter_modulus)
    n_left = _counts(np.asarray(inputs.left_pulses, np.float64), modulus, expected)
    n_right = _counts(np.asarray(inputs.right_pulses, np.float64), modulus, expected)
    # A sample no car can drive (one wheel 1.5x the other and more than quantization: a burst) or a missing count
    # leaves its window out, as does one the model found implausible: a glitch is a leverage point of (1).
    impossible = np.abs(n_left - n_right) > 0.5 * np.abs(n_left + n_right) + 2.0
    bad = ~(np.isfinite(n_left) & np.isfinite(n_right)) | (np.asarray(odometer_ok) < 0.5) | impossible
    n_left, n_right = np.where(bad, 0.0, n_left), np.where(bad, 0.0, n_right)
    # A step in time_s longer than two windows' share (a logger gap) ends the windows around it.
    gap = np.concatenate([[False], np.diff(t) > 0.5 * window_s])
    cum_bad = np.cumsum(bad | gap)
    edges = np.unique(np.searchsorted(t, t[0] + window_s * np.arange(int((t[-1] - t[0]) // window_s) + 1)))
    start, end = edges[:-1], edges[1:]
    heading = np.asarray(compass_heading, np.float64)
    ok_c = (np.asarray(compass_ok) > 0.5) & np.isfinite(heading)
    d_heading = np.angle(np.exp(1j * (heading[end] - heading[start])))
    use = ok_c[start] & ok_c[end] & (cum_bad[end] == cum_bad[start]) & (t[end] - t[start] <= 1.5 * window_s)
    track = float(params.T_F if float(params.sensor_axle) > 0.5 else params.T_R)  # T_E(0) = T_F by eq. (14)
    scale = 1.0
    for _ in range(2):
        velocity = 1.0 / (1.0 + float(params.a) * (scale * speed) ** 2)
        cum_left, cum_right = np.cumsum(n_left * velocity), np.cumsum(n_right * velocity)
        win_left, win_right = cum_left[end] - cum_left[start], cum_right[end] - cum_right[start]
        used = use & (win_left + win_right >= MIN_WINDOW_PULSES)
        if used.sum() < MIN_WINDOWS or np.degrees(np.abs(d_heading[used]).sum()) < MIN_TURN_DEG:
            return None
        solved = _huber_fit(np.stack([win_left[used], -win_right[used]], axis=1) / track, d_heading[used])
        if solved is None:
            return None
        (dpp_left, dpp_right), sigma, cov = solved
        scale = 0.5 * (dpp_left + dpp_right) / nominal
    mean = 0.5 * (dpp_left + dpp_right)
    if not (DPP_RANGE[0] * nominal <= min(dpp_left, dpp_right) and max(dpp_left, dpp_right) <= DPP_RANGE[1] * nominal
            and abs(dpp_right / dpp_left - 1.0) <= MAX_RATIO):
        return None
    scale_se = 0.5 * np.sqrt(max(cov[0, 0] + cov[1, 1] + 2 * cov[0, 1], 0.0)) / mean
    if scale_se > MAX_SCALE_SE:
        return None
    if abs(dpp_right / dpp_left - 1.0) < EQUAL_TYRES:
        dpp_left = dpp_right = mean
    return WheelScales(float(dpp_left), float(dpp_right), int(used.sum()), float(scale_se), float(np.degrees(sigma)))


def from_compass(params, drive, config=None) -> WheelScales | None:
    """``fit`` on the drive, its compass heading and validity from the model itself: ``config`` (a jaxmodel.Config,
    the default one when None: its hard-iron learning, filter, ...) in compass mode, ``params``."""
    import jaxmodel

    from .estimate import run_padded

    out = run_padded(params, drive, (config or jaxmodel.Config())._replace(mode="compass"))
    return fit(params, drive, np.asarray(out.compass_heading), np.asarray(out.compass_valid),
               np.asarray(out.odometer_valid), np.asarray(out.speed))


def ratio_from_reference(params, drives) -> float | None:
    """The tyres' ratio dpp_right / dpp_left that (1) finds with the drives' reference heading (``ref_heading``, rad)
    in place of H_C: the median over the drives that can tell (``fit``), None where none can.  ``identify`` starts a
    fitted dpp from it (a 1.25 % mismatch turns the wheel heading by 200 deg within its 30-s increments)."""
    ratios = []
    for drive in drives:
        if drive.ref_heading is None:
            continue
        ref = np.asarray(drive.ref_heading, np.float64)
        scales = fit(params, drive, np.nan_to_num(ref), np.isfinite(ref), np.ones_like(ref))
        if scales is not None:
            ratios.append(scales.dpp_right / scales.dpp_left)
    return float(np.median(ratios)) if ratios else None


def applied(params, scales: WheelScales | None):
    """``params`` with the fitted distances per pulse (unchanged when ``scales`` is None)."""
    if scales is None:
        return params
    return params._replace(dpp_left=np.float64(scales.dpp_left), dpp_right=np.float64(scales.dpp_right))


def dpp_unknown(given_keys) -> bool:
    """True when a parameter file set neither ``dpp_left`` nor ``dpp_right`` (its ``extra["keys"]``): the wheels'
    scale is then found from the compass, whatever else of the vehicle the file gives."""
    from jaxmodel import DPP_KEYS

    return not (set(DPP_KEYS) & set(given_keys))


def for_drive(params, fit_dpp: bool, drive, config):
    """(params, WheelScales or None): where the distance per pulse is unknown (``fit_dpp``, ``dpp_unknown``) and
    ``config`` (a jaxmodel.Config) reads the wheels, the distances per pulse found from the drive's own compass (in
    ``config``'s compass mode); else ``params`` unchanged.  The one place ``estimate`` and ``fleet evaluate`` decide
    it."""
    if not fit_dpp or config.mode == "compass":
        return params, None
    scales = from_compass(params, drive, config)
    return applied(params, scales), scales


def describe(scales: WheelScales | None, params) -> str:
    """One line for the user: what the wheels' distance per pulse is and where it came from."""
    if scales is None:
        return (f"the nominal distance per pulse ({float(params.dpp_left):g} m) kept: the drive's compass could not "
                f"tell the wheels' (too short, too straight, no compass, or too disturbed)")
    return (f"distance per pulse from the drive's own compass: left {scales.dpp_left:.6g} m, right "
            f"{scales.dpp_right:.6g} m ({scales.n_windows} windows of {WINDOW_S:g} s, scale +-"
            f"{100 * scales.scale_se:.1f} %)")
