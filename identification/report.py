"""Statistics and the human-readable side of an identification: Laplace standard errors,
correlations, identifiability verdicts, RMSE tables.

Standard errors come from the Gauss-Newton approximation of the Hessian of the MAP objective in
the whitened coordinates z (prior N(0, I)): H = J^T W J / sigma² + I.  The posterior covariance
is H^-1; in physical units the delta method multiplies by d theta / d z (diagonal).  Because the
prior has unit variance in z, sqrt(diag(H^-1)) is directly "posterior std / prior std":

* >= NOT_IDENTIFIABLE_RATIO (0.9): the data hardly constrain the parameter; it is reported as
  not identifiable and kept at its starting value (the fit does not invent it);
* >= WEAK_RATIO (0.5): weakly identified, mostly the prior;
* pairs with |correlation| > CORRELATION_LIMIT (0.95): only their combination is identified.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

NOT_IDENTIFIABLE_RATIO = 0.9
WEAK_RATIO = 0.5
CORRELATION_LIMIT = 0.95


def laplace(hess: np.ndarray, dtheta_dz: np.ndarray):
    """(cov_z, std ratio, std error in physical units, correlation) from the GN Hessian in z."""
    hess = np.asarray(hess, dtype=np.float64)
    hess = 0.5 * (hess + hess.T)
    try:
        cov = np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(hess)
    var = np.clip(np.diag(cov), 0.0, None)
    ratio = np.sqrt(var)
    se = np.abs(dtheta_dz) * ratio
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(ratio, ratio)
    corr = np.where(np.isfinite(corr), np.clip(corr, -1.0, 1.0), 0.0)
    np.fill_diagonal(corr, 1.0)
    return cov, ratio, se, corr


def verdict(ratio: float, signal: bool) -> str:
    if not signal or ratio >= NOT_IDENTIFIABLE_RATIO:
        return "not identifiable"
    if ratio >= WEAK_RATIO:
        return "weak"
    return "identified"


def correlated_pairs(labels: Sequence[str], corr: np.ndarray, limit: float = CORRELATION_LIMIT):
    out = []
    for i in range(len(labels)):
        for j in range(i + 1, len(labels)):
            if abs(corr[i, j]) > limit:
                out.append((labels[i], labels[j], float(corr[i, j])))
    return out


def rmse_deg(err_rad: np.ndarray, weight: np.ndarray, align: bool = False) -> float:
    """Weighted RMSE (deg) of wrapped errors; ``align`` removes their circular mean first."""
    e = np.asarray(err_rad, dtype=np.float64)
    w = np.asarray(weight, dtype=np.float64)
    if not np.any(w > 0):
        return float("nan")
    e = np.angle(np.exp(1j * e))
    if align:
        b = math.atan2(np.sum(w * np.sin(e)), np.sum(w * np.cos(e)))
        e = np.angle(np.exp(1j * (e - b)))
    return float(np.degrees(np.sqrt(np.sum(w * e * e) / np.sum(w))))


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.6g}"


def format_summary(report: dict) -> str:
    """Tables of parameters and per-drive RMSE for the terminal."""
    lines = []
    params = report.get("parameters", {})
    if params:
        lines.append(f"{'parameter':22s} {'start':>12s} {'fitted':>12s} {'std error':>11s} {'post/prior':>10s}  status")
        for k, row in params.items():
            lines.append(f"{k:22s} {_fmt(row.get('start')):>12s} {_fmt(row.get('fitted')):>12s} "
                         f"{_fmt(row.get('std_error')):>11s} {_fmt(row.get('posterior_to_prior_std')):>10s}  "
                         f"{row.get('status', '')}")
    drives = report.get("drives", [])
    if drives:
        heading = report.get("rmse_heading", "heading")
        lines.append("")
        lines.append(f"{'drive':44s} {'RMSE before':>11s} {'RMSE after':>11s}   ({heading}, deg)")
        for row in drives:
            shown = row["name"] if len(row["name"]) <= 34 else "..." + row["name"][-31:]
            name = f"{row['role']}: {shown}"
            lines.append(f"{name:44s} {row['rmse_before_deg']:11.3f} {row['rmse_after_deg']:11.3f}")
    lines.append("")
    lines.append(f"iterations {report.get('iterations')}, objective evaluations {report.get('evaluations')}, "
                 f"wall time {report.get('wall_time_s', float('nan')):.1f} s")
    return "\n".join(lines)
