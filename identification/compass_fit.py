"""Compass calibration identified with the vehicle (issue 14): which keys, on which heading, and the
deviation table as a smooth curve.

US 4,734,863 FIG. 8A forms H_C = atan2(Y - Y0, X - X0) + deviation(A) - R + V, A the raw angle,
the deviation a 36-entry table over A (10° apart, interpolated).  Identified from drives:

* ``X0``, ``Y0`` (hard iron), ``rotation_deg`` (R), ``variation_deg`` (V) and ``deviation_deg``
  are fitted on the **compass heading** itself (estimator mode ``compass``): it depends on them
  directly, sample by sample, whereas the complementary heading only sees them through a filter
  whose distance constant (D_N, kilometres) averages a heading-dependent error away.  Against a
  reference heading the error is absolute; against fixes it is the course of chords of the
  compass-mode track (``fixes_loss``), which knows true north.
* The deviation table is never 36 free numbers: it is the start table plus the harmonics of A of
  the classical compass deviation formula (Archibald Smith: delta = A + B sin + C cos + D sin 2 + E cos 2),

      deviation(A_j) = start_j + sum_k (c_k cos k A_j + s_k sin k A_j),   k in DEVIATION_HARMONICS

  fitted as the coefficients (degrees).  The constant (k = 0) is not among them: it is R.  The
  first harmonic is, to first order in |offset|/|field|, exactly the heading error of a hard-iron
  offset (atan2(H sin A + Y0', H cos A + X0') - A ~ (Y0' cos A - X0' sin A) / H), so when X0 or Y0
  is fitted too the harmonics start at 2 (soft iron, which distorts the field circle into an
  ellipse, is a second harmonic).  Higher harmonics are left out: measured on simulated drives, a
  third harmonic fitted the route-specific dip errors of road grade (0.6-1.0° on 40 minutes, 3
  reported standard errors) and made held-out headings worse (docs/identification.md).
  R and V are one constant in H_C: fitting both reports their
  correlation (-1) and "only their combination is identified"; so does an offset on a drive that
  never turns.
"""

from __future__ import annotations

import math

import numpy as np

DEVIATION_TABLE_SIZE = 36
MAX_HARMONIC = 2
COMPASS_KEYS = ("X0", "Y0", "rotation_deg", "variation_deg", "deviation_deg")
"""Keys that act on the compass heading alone (FIG. 8A); fitted in stage 'compass' on that heading."""


def deviation_harmonics(fit_keys) -> tuple[int, ...]:
    """Harmonic orders of the deviation curve: (2,) when X0 or Y0 is fitted too, else (1, 2)."""
    first = 2 if ("X0" in fit_keys or "Y0" in fit_keys) else 1
    return tuple(range(first, MAX_HARMONIC + 1))


def harmonic_basis(orders) -> np.ndarray:
    """(36, 2 len(orders)) matrix B with B[j, 2i] = cos(k_i A_j), B[j, 2i+1] = sin(k_i A_j), A_j = 10° j."""
    a = np.radians(np.arange(DEVIATION_TABLE_SIZE) * (360.0 / DEVIATION_TABLE_SIZE))
    cols = []
    for k in orders:
        cols.append(np.cos(k * a))
        cols.append(np.sin(k * a))
    return np.stack(cols, axis=1)


def harmonic_labels(key: str, orders) -> list[str]:
    out = []
    for k in orders:
        out += [f"{key}[cos{k}]", f"{key}[sin{k}]"]
    return out


def project(table, orders) -> np.ndarray:
    """Least-squares harmonic coefficients (deg) of a 36-entry table (the start values of the curve)."""
    b = harmonic_basis(orders)
    coef, *_ = np.linalg.lstsq(b, np.asarray(table, dtype=np.float64).reshape(-1), rcond=None)
    return coef


def table_from_harmonics(coefficients, orders) -> np.ndarray:
    """36-entry deviation table (deg) of the given harmonic coefficients."""
    return harmonic_basis(orders) @ np.asarray(coefficients, dtype=np.float64)


def soft_iron_table(amplitude_deg: float = 1.0, phase_deg: float = 30.0, third_deg: float = 0.0) -> np.ndarray:
    """A soft-iron deviation table for simulations: amplitude x cos(2A - phase) (+ a small third harmonic)."""
    a = np.radians(np.arange(DEVIATION_TABLE_SIZE) * (360.0 / DEVIATION_TABLE_SIZE))
    ph = np.radians(phase_deg)
    return amplitude_deg * np.cos(2.0 * a - ph) + third_deg * np.sin(3.0 * a)


# ----------------------------------------------------------------------------------------------
# the hard-iron offset from the field circle (no reference needed)

FIELD_CIRCLE_CORRELATION_M = 250.0
"""Travelled distance over which the raw field's errors (road grade and body roll leaking the
vertical field, anomalies) are taken as correlated: the circle fit's least-squares covariance is
scaled by (samples used) / (distance / this), so that it counts one independent error per this
many metres (chosen on simulation seeds 3-7, docs/identification.md)."""


FIELD_CIRCLE_MIN_ARC_DEG = 120.0
"""The field directions around the fitted centre must span at least this arc (the mean resultant
length of a uniform arc of that width), as ``hard_iron_min_turn_deg`` of the online estimate."""


FIELD_CIRCLE_MIN_RADIUS_RESIDUALS = 6.0
"""The fitted radius must be at least this many times the residuals' RMS.  A drive that hardly turns (a minute in
town, samples within a microtesla of each other) fits a circle of the noise's size through them, spanning the arc
around its own centre: radius 0.3-0.8 uT, 2.1-3.8 residuals, its centre 20 uT off (stop 46, matrix drives' first
20-60 s).  Real circles: 11-43 residuals on the independent simulator's drives (grades of 8-10 % the lowest), 13-89
on the matrix's."""


def spans_arc(resultant: float, arc_deg: float = FIELD_CIRCLE_MIN_ARC_DEG) -> bool:
    """Directions whose mean resultant length is ``resultant`` span at least ``arc_deg`` (a uniform arc of width A
    has sin(A/2) / (A/2))."""
    half = math.radians(arc_deg) / 2.0
    return resultant <= math.sin(half) / half


def field_circle(inputs, mask, params, correlation_m: float = FIELD_CIRCLE_CORRELATION_M,
                 iterations: int = 20):
    """The centre (X0, Y0) of the circle the raw horizontal field draws while the vehicle turns, and
    its covariance: ``(centre (2,), covariance (2, 2), info dict)`` or None when there is no usable
    circle (too few samples, a fit that does not converge).

    The horizontal field lies on a circle around the hard-iron offset whatever the reference
    (US 4,734,863 calibrates X0, Y0 from a full turn; jaxmodel/hard_iron.py does it online).  Moving
    samples outside map-flagged unreliable areas, every drive of the batch pooled (one sensor, one
    offset): an algebraic (Kåsa) fit starts a geometric fit, |B - c| - r, by Gauss-Newton with Cauchy
    weights at twice the residuals' MAD (anomalies); None unless the field directions around the
    centre span ``FIELD_CIRCLE_MIN_ARC_DEG`` and its radius ``FIELD_CIRCLE_MIN_RADIUS_RESIDUALS``
    times the residuals' RMS.  Its covariance sigma² (JᵀWJ)⁻¹ is inflated to
    one independent error per ``correlation_m`` of travel; on a drive that never turns it is huge
    across the unseen direction, so the circle then says nothing there."""
    from .loss import travelled_distance

    cx = np.asarray(inputs.compass_x, dtype=np.float64)
    cy = np.asarray(inputs.compass_y, dtype=np.float64)
    dist = travelled_distance(inputs, params)
    ds = np.diff(dist, axis=-1, prepend=dist[..., :1])
    ok = ((np.asarray(mask) > 0.5) & np.isfinite(cx) & np.isfinite(cy) & (ds > 0)
          & (np.asarray(inputs.compass_unreliable_area) < 0.5))
    x, y = cx[ok], cy[ok]
    distance = float(np.sum(ds[ok]))
    if x.size < 10 or not distance > 0:
        return None
    a = np.stack([x, y, np.ones_like(x)], axis=1)
    k, *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
    c = np.array([k[0] / 2.0, k[1] / 2.0])
    r = math.sqrt(max(k[2] + c @ c, 1e-12))
    w = np.ones_like(x)
    for _ in range(iterations):
        dx, dy = x - c[0], y - c[1]
        d = np.maximum(np.hypot(dx, dy), 1e-9)
        res = d - r
        scale = 2.0 * 1.4826 * float(np.median(np.abs(res))) + 1e-9
        w = 1.0 / (1.0 + (res / scale) ** 2)
        jac = np.stack([-dx / d, -dy / d, -np.ones_like(d)], axis=1)
        sw = np.sqrt(w)
        step = np.linalg.lstsq(jac * sw[:, None], -res * sw, rcond=None)[0]
        c, r = c + step[:2], r + step[2]
        if not (np.all(np.isfinite(c)) and math.isfinite(r) and r > 0):
            return None
        if np.max(np.abs(step)) < 1e-9:
            break
    dx, dy = x - c[0], y - c[1]
    d = np.maximum(np.hypot(dx, dy), 1e-9)
    # a circle is only determined by an arc of field directions (a short arc fits a small circle as
    # well as the true one): as the online estimate, at least FIELD_CIRCLE_MIN_ARC_DEG around the centre
    resultant = float(np.hypot(np.sum(w * dx / d), np.sum(w * dy / d)) / np.sum(w))
    if not spans_arc(resultant):
        return None
    res = d - r
    jac = np.stack([-dx / d, -dy / d, -np.ones_like(d)], axis=1)
    sigma2 = float(np.sum(w * res * res) / max(np.sum(w) - 3.0, 1.0))
    if r < FIELD_CIRCLE_MIN_RADIUS_RESIDUALS * math.sqrt(sigma2):
        return None  # a circle of the noise's size: the samples say nothing of the offset
    info_m = (jac * w[:, None]).T @ jac
    try:
        cov3 = sigma2 * np.linalg.inv(info_m)
    except np.linalg.LinAlgError:
        return None
    n_eff = max(distance / float(correlation_m), 1.0)
    cov = cov3[:2, :2] * (x.size / n_eff)
    if not np.all(np.isfinite(cov)):
        return None
    return c, cov, {"radius": float(r), "samples": int(x.size), "distance_m": distance,
                    "residual_ut": math.sqrt(sigma2), "correlation_m": float(correlation_m)}
