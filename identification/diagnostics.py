"""Warnings where a result is probably wrong (issue 11), shared by ``estimate`` and ``identify``.

``drive_warnings(drive, params, columns)`` looks at one drive, the parameters it was estimated
with and the per-sample table of ``estimate_drive`` (or the same columns from a batch run) and
returns one line per problem, each naming the drive:

* **no usable compass**: every compass sample was invalid (NaN/inf or no field) — the heading is
  the wheels' alone, with an unknown start;
* **uncalibrated compass**: the median measured horizontal field (after X0/Y0) far from
  ``field_magnitude`` (outside ``FIELD_RATIO``), or the circle the field draws while turning centred off
  X0/Y0 (``FIELD_OFFSET``: hard iron not removed), or a persistent disagreement of tens of degrees between the
  compass and the reference heading (when the log has one) or the estimated heading (its mean over
  ``WINDOW_S`` windows, DELTA less what the filter explains);
* **counter_modulus mismatch**: counters at or above ``counter_modulus`` (they never reach it if
  they wrap there), or counters that fall back by more than half their range (a wrap) while never
  coming near the modulus (they wrap elsewhere), with the time of the first;
* **a counter that stopped counting** while the other counted on, for a second or more, with the times;
* **odometer samples that failed** the plausibility checks (``odometer_valid`` = 0), with their times: the guard
  replaced their motion by its prediction where their counts were finite (how many were not, if any);
* **time not in seconds**: a median time step of ``SLOW_STEP_S`` or more (milliseconds read as seconds make
  every speed 1000 x too small, and the speed gates of the refinement never open).

``checked_params(path)`` loads and validates a parameter file with every error naming the file.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

FIELD_RATIO = (0.75, 1.33)
"""Median measured |B| / field_magnitude outside this range: the compass looks uncalibrated."""
FIELD_OFFSET = 0.15
"""The field circle's centre (compass_fit.field_circle) this far from X0/Y0, as a fraction of its radius: hard
iron not removed (the magnitude then varies with heading by twice that).  The centre, not the spread of the
magnitude per heading, since stop 45: on grades the compass's tilt (dip error) spreads the magnitude by 30 %
on a calibrated compass (bench/independent_sim.py, urban_hilly seed 2: spread 0.32, centre 0.08 off)."""
DISAGREE_DEG = 15.0
"""A mean compass error (against the reference or the estimate) of this many degrees ..."""
DISAGREE_FRACTION = 0.25
"""... in at least this fraction of the windows counts as persistent."""
WINDOW_S = 60.0
MAX_TIMES_SHOWN = 5
SLOW_STEP_S = 5.0
"""A median time step this long (s) is no wheel-odometry log: time_s is probably in milliseconds."""


def checked_params(path, label: str = "--params"):
    """(Params, extra) from ``path`` (validated), or the built-in defaults when ``path`` is None
    (extra["keys"]: the keys the file set).  Every ParameterError names the file."""
    import jaxmodel

    if path is None:
        params, extra, name = jaxmodel.make_params(), {"keys": ()}, "built-in defaults"
    else:
        params, extra = jaxmodel.load_params(path)
        name = str(path)
    try:
        jaxmodel.validate_params(params)
    except jaxmodel.ParameterError as exc:
        raise jaxmodel.ParameterError(f"{name}: {exc}") from None
    return params, extra


def estimation_params(path, label: str = "--params"):
    """(Params, extra, nominal_vehicle): ``checked_params`` for running the estimator, with the turn-scale state of
    a vehicle nobody gave switched on where the file does not give the wheel turn's scale
    (``jaxmodel.for_unidentified_vehicle``).
    The one place that decides it, for ``estimate`` and ``fleet evaluate`` alike."""
    import jaxmodel

    params, extra = checked_params(path, label)
    params, nominal_vehicle = jaxmodel.for_unidentified_vehicle(params, extra["keys"])
    return params, extra, nominal_vehicle


def _times(t: np.ndarray) -> str:
    shown = ", ".join(f"{v:.1f}" for v in t[:MAX_TIMES_SHOWN])
    more = f" and {t.size - MAX_TIMES_SHOWN} more" if t.size > MAX_TIMES_SHOWN else ""
    return f"t = {shown}{more} s"


def _wrap_deg(a):
    return (np.asarray(a, dtype=np.float64) + 180.0) % 360.0 - 180.0


def _window_means(t: np.ndarray, err_deg: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Circular means of err_deg (degrees) over consecutive WINDOW_S windows with enough samples."""
    if not np.any(ok):
        return np.zeros(0)
    idx = np.floor((t - t[0]) / WINDOW_S).astype(np.int64)
    n = int(idx.max()) + 1
    c = np.bincount(idx[ok], weights=np.cos(np.deg2rad(err_deg[ok])), minlength=n)
    s = np.bincount(idx[ok], weights=np.sin(np.deg2rad(err_deg[ok])), minlength=n)
    k = np.bincount(idx[ok], minlength=n)
    full = k >= max(5, 0.2 * np.median(k[k > 0]))
    return np.rad2deg(np.arctan2(s[full], c[full]))


def _turned_enough(cols, valid) -> bool:
    """The wheels' heading spans compass_fit.FIELD_CIRCLE_MIN_ARC_DEG (mean resultant length of its moving samples):
    the fit's own arc test is around its centre, and a short arc of noisy samples fits a small circle anywhere
    whose centre it surrounds (a 20-s drive: radius 0.5 uT, 20 uT away)."""
    from .compass_fit import spans_arc

    moving = valid & (np.asarray(cols.get("speed_mps", np.ones(valid.size))) > 0.0)
    psi = np.deg2rad(np.asarray(cols["wheel_heading_deg"], dtype=np.float64)[moving])
    psi = psi[np.isfinite(psi)]
    return psi.size >= 20 and spans_arc(float(np.abs(np.mean(np.exp(1j * psi)))))


def _hard_iron_warnings(name, drive, params, cols, valid) -> list[str]:
    """The circle the raw field draws while turning, centred off X0/Y0 by more than FIELD_OFFSET of its radius."""
    from .compass_fit import field_circle

    if "wheel_heading_deg" not in cols or not _turned_enough(cols, valid):
        return []
    fit = field_circle(drive.inputs, valid.astype(np.float64), params)
    if fit is None:  # too few samples to tell
        return []
    centre, cov, info = fit
    off = float(np.hypot(centre[0] - float(params.X0), centre[1] - float(params.Y0)))
    radius = float(info["radius"])
    sure = float(np.sqrt(np.max(np.linalg.eigvalsh(cov)))) < 0.5 * off
    if not (radius > 0 and off > FIELD_OFFSET * radius and sure):
        return []
    return [f"{name}: the compass looks uncalibrated: the measured field circles around ({centre[0]:.4g}, "
            f"{centre[1]:.4g}), {off:.3g} off X0/Y0 = ({float(params.X0):.4g}, {float(params.Y0):.4g}) "
            f"({off / radius:.0%} of its radius {radius:.4g}): a hard-iron offset not removed; set X0/Y0 "
            f"(identify --fit X0,Y0) or run estimate --hard-iron on"]


def _compass_warnings(name, drive, params, cols, mode="complementary") -> list[str]:
    from jaxmodel.params import field_magnitude_given

    out = []
    valid = np.asarray(cols["compass_valid"]) > 0
    n = valid.size
    if not np.any(valid):
        fixes = np.asarray(drive.inputs.fix_valid, dtype=np.float64)
        if mode == "compass":
            consequence = "the compass mode has no heading to give (heading_deg is no estimate, reliability least)"
        elif mode == "kalman" and np.any(fixes > 0.5):
            consequence = ("the Kalman mode starts the heading from the position fixes once they agree with the "
                           "wheels' track (heading_deg is no estimate before, reliability least)")
        else:
            consequence = "the heading comes from the wheels alone and its start is unknown"
            if np.any(fixes > 0.5):
                consequence += " (the drive has position fixes: --mode kalman starts the heading from them)"
        return [f"{name}: no usable compass: all {n} compass samples are invalid (NaN or infinite, both "
                f"components exactly 0, or one reading repeated while the wheels turned); {consequence}"]
    cx = np.asarray(drive.inputs.compass_x, dtype=np.float64) - float(params.X0)
    cy = np.asarray(drive.inputs.compass_y, dtype=np.float64) - float(params.Y0)
    mag = np.hypot(cx, cy)
    ok = valid & np.isfinite(mag)
    b_e = float(params.field_magnitude)
    if np.any(ok):
        med = float(np.median(mag[ok]))
        if field_magnitude_given(params) and not FIELD_RATIO[0] <= med / b_e <= FIELD_RATIO[1]:
            out.append(f"{name}: the compass looks uncalibrated: measured horizontal field {med:.4g} "
                       f"(median) against field_magnitude {b_e:.4g} (x{med / b_e:.2f}); check the compass "
                       f"offsets X0/Y0 and its scale, or field_magnitude")
        else:
            out += _hard_iron_warnings(name, drive, params, cols, valid)
    t = np.asarray(cols["time_s"], dtype=np.float64)
    comp = np.asarray(cols["compass_heading_deg"], dtype=np.float64)
    ref = None if drive.ref_heading is None else np.rad2deg(np.asarray(drive.ref_heading, dtype=np.float64))
    if ref is not None and np.any(np.isfinite(ref) & valid):
        okr = valid & np.isfinite(ref)
        err = _wrap_deg(comp - np.where(okr, ref, 0.0))
        means = _window_means(t, err, okr)
        bad = np.abs(means) >= DISAGREE_DEG
        if means.size and np.mean(bad) >= DISAGREE_FRACTION:
            mean_all = float(np.rad2deg(np.arctan2(np.mean(np.sin(np.deg2rad(err[okr]))),
                                                   np.mean(np.cos(np.deg2rad(err[okr]))))))
            rms = float(np.sqrt(np.mean(err[okr] ** 2)))
            out.append(f"{name}: the compass looks uncalibrated: it is off the reference heading by {rms:.0f} deg "
                       f"RMS (mean {mean_all:+.0f} deg), by {DISAGREE_DEG:g} deg or more on average in "
                       f"{np.mean(bad):.0%} of the {WINDOW_S:g}-s windows")
    elif "heading_deg" in cols:
        est = np.asarray(cols["heading_deg"], dtype=np.float64)
        if not np.allclose(_wrap_deg(est[valid] - comp[valid]), 0.0, atol=1e-9):  # not compass mode
            err = _wrap_deg(comp - est)
            means = _window_means(t, err, valid)
            bad = np.abs(means) >= DISAGREE_DEG
            if means.size >= 3 and np.mean(bad) >= DISAGREE_FRACTION:
                out.append(f"{name}: the compass looks uncalibrated or disturbed: its heading departs from the "
                           f"estimate by {DISAGREE_DEG:g} deg or more (mean DELTA over {WINDOW_S:g} s, less the "
                           f"filter's offset) in {np.mean(bad):.0%} of the windows")
    return out


def _counter_warnings(name, drive, params) -> list[str]:
    out = []
    modulus = float(params.counter_modulus)
    t = np.asarray(drive.inputs.time_s, dtype=np.float64)
    for side in ("left", "right"):
        c = np.asarray(getattr(drive.inputs, f"{side}_pulses"), dtype=np.float64)
        fin = np.isfinite(c)
        if not np.any(fin):
            continue
        over = np.flatnonzero(fin & (c >= modulus))
        if over.size:
            out.append(f"{name}: counter_modulus {modulus:.0f} does not match the counters: {side}_pulses reaches "
                       f"{np.max(c[fin]):.0f} ({over.size} samples at or above the modulus, first at "
                       f"t = {t[over[0]]:.1f} s); the counters cannot wrap at {modulus:.0f}")
            break
        d = np.diff(c)
        top = np.max(c[fin])
        drops = np.flatnonzero(np.isfinite(d) & (d < -0.5 * top))  # a wrap, not a short reverse
        if drops.size:
            if top < 0.5 * modulus:  # wraps, but far below the modulus
                out.append(f"{name}: counter_modulus {modulus:.0f} does not match the counters: {side}_pulses falls "
                           f"from {c[drops[0]]:.0f} to {c[drops[0] + 1]:.0f} at t = {t[drops[0] + 1]:.1f} s but "
                           f"never exceeds {top:.0f}; they seem to wrap near {top + 1:.0f}")
                break
    return out


def _stopped_counter_warnings(name, drive, params) -> list[str]:
    """Runs of at least STOPPED_MIN_S in which one counter did not change while the other counted at least
    STOPPED_OTHER_PULSES per sample: a wheel sensor that stopped counting (no wheel of a car stands still while
    the other rolls; plausibility.impossible replaces such samples where it can tell them from a turn)."""
    out = []
    from jaxmodel.plausibility import STOPPED_MIN_S, STOPPED_OTHER_PULSES

    from .drive_log import counter_increments

    t = np.asarray(drive.inputs.time_s, dtype=np.float64)
    # inc[side][i]: from sample i to i + 1
    inc = {side: counter_increments(getattr(drive.inputs, f"{side}_pulses"), float(params.counter_modulus))[1:]
           for side in ("left", "right")}
    for side, other in (("left", "right"), ("right", "left")):
        stopped = (inc[side] == 0.0) & (np.abs(inc[other]) >= STOPPED_OTHER_PULSES)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], stopped.astype(np.int8), [0]])))
        runs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if t[b] - t[a] >= STOPPED_MIN_S]
        if runs:
            shown = ", ".join(f"t = {t[a + 1]:.1f}-{t[b]:.1f} s" for a, b in runs[:MAX_TIMES_SHOWN])
            more = f" and {len(runs) - MAX_TIMES_SHOWN} more" if len(runs) > MAX_TIMES_SHOWN else ""
            out.append(f"{name}: {side}_pulses stopped counting while {other}_pulses counted on ({shown}{more}): a "
                       f"wheel sensor fault; its samples were replaced by the other wheel's travel where the guard "
                       f"could tell them from a turn (front-axle sensors, or wheel speeds above ~6 m/s)")
    return out


def _odometer_warnings(name, drive, cols) -> list[str]:
    odo = np.asarray(cols["odometer_valid"])
    bad = np.flatnonzero(odo[1:] == 0) + 1  # the first sample only sets the counter references
    if not bad.size:
        return []
    t = np.asarray(cols["time_s"], dtype=np.float64)[bad]
    # The robust estimator's guard (jaxmodel/plausibility.py) replaces the motion of a sample whose finite counts
    # failed a check by its prediction (a spike, a wrap at another modulus); counts that are not numbers carry none.
    counts = [np.asarray(getattr(drive.inputs, f"{side}_pulses"), dtype=np.float64)[bad] for side in ("left", "right")]
    non_finite = int(np.sum(~(np.isfinite(counts[0]) & np.isfinite(counts[1]))))
    what = "the guard replaced their motion by its prediction where the counts were finite" + (
        f" ({non_finite} were not)" if non_finite else "")
    return [f"{name}: {bad.size} odometer samples failed the plausibility checks (implausible or non-finite "
            f"counts) at {_times(t)}: {what}"]


def _time_warnings(name, drive) -> list[str]:
    t = np.asarray(drive.inputs.time_s, dtype=np.float64)
    if t.size < 3:
        return []
    step = float(np.median(np.diff(t)))
    if step < SLOW_STEP_S:
        return []
    return [f"{name}: the median time step is {step:.4g} s, too long for a wheel-odometry log: is time_s in "
            f"milliseconds? (then every speed reads 1000 x too small)"]


def drive_warnings(drive, params, cols: Mapping[str, np.ndarray], mode="complementary") -> list[str]:
    """Warnings for one drive (see the module docstring); ``cols`` as returned by ``estimate_drive`` in ``mode``."""
    name = drive.path
    return (_time_warnings(name, drive) + _compass_warnings(name, drive, params, cols, mode)
            + _counter_warnings(name, drive, params)
            + _stopped_counter_warnings(name, drive, params) + _odometer_warnings(name, drive, cols))


def batch_warnings(drives, params, config=None) -> list[str]:
    """``drive_warnings`` for several drives, estimated in one compiled batch (``identify``)."""
    import jax
    import jax.numpy as jnp

    import jaxmodel

    from .drive_log import stack_drives, wrap_deg

    if not drives:
        return []
    config = jaxmodel.Config(mode="complementary") if config is None else config
    inputs, _mask = stack_drives(list(drives))
    out = jax.device_get(jaxmodel.run_batch(params, jax.tree_util.tree_map(jnp.asarray, inputs), config))
    warnings = []
    for b, d in enumerate(drives):
        n = len(np.asarray(d.inputs.time_s))
        cols = {"time_s": np.asarray(d.inputs.time_s, dtype=np.float64),
                "heading_deg": wrap_deg(np.rad2deg(np.asarray(out.heading[b, :n]))),
                "compass_heading_deg": wrap_deg(np.rad2deg(np.asarray(out.compass_heading[b, :n]))),
                "wheel_heading_deg": wrap_deg(np.rad2deg(np.asarray(out.wheel_heading[b, :n]))),
                "speed_mps": np.asarray(out.speed[b, :n]),
                "compass_valid": np.asarray(out.compass_valid[b, :n]),
                "odometer_valid": np.asarray(out.odometer_valid[b, :n])}
        warnings += drive_warnings(d, params, cols)
    return warnings
