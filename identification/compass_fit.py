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
