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


def _fmt3(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.3f}"


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
        fixes = any("fix_course_rmse_before_deg" in row for row in drives)
        lines.append("")
        lines.append(f"reference: {report.get('reference', 'heading')}")
        extra = f" {'course vs fixes':>17s} {'position vs fixes':>19s}" if fixes else ""
        lines.append(f"{'drive':44s} {'RMSE before':>11s} {'RMSE after':>11s}{extra}   ({heading}, deg; m)")
        prim = "odometer" if report.get("mode", "odometer") == "odometer" else \
            ("kalman" if report.get("mode") == "kalman" else "complementary")
        for row in drives:
            shown = row["name"] if len(row["name"]) <= 34 else "..." + row["name"][-31:]
            name = f"{row['role']}: {shown}"
            line = f"{name:44s} {_fmt3(row['rmse_before_deg']):>11s} {_fmt3(row['rmse_after_deg']):>11s}"
            if fixes:
                c = f"{_fmt3(row.get('fix_course_rmse_before_deg'))} -> {_fmt3(row.get('fix_course_rmse_after_deg'))}"
                pos = (f"{_fmt3(row.get(f'{prim}_position_rmse_before_m'))} -> "
                       f"{_fmt3(row.get(f'{prim}_position_rmse_after_m'))}")
                line += f" {c:>17s} {pos:>19s}"
            lines.append(line)
    lines.append("")
    lines.append(f"iterations {report.get('iterations')}, objective evaluations {report.get('evaluations')}, "
                 f"wall time {report.get('wall_time_s', float('nan')):.1f} s")
    return "\n".join(lines)


def identifiability_context(ev_after: dict, n_train: int) -> dict:
    """Figures of the training drives quoted in the identifiability hints (identify.KEY_HINTS)."""
    w_train = ev_after["weight"][:n_train] > 0
    if not np.any(w_train):  # no reference heading (fixes): every real, started sample
        w_train = ev_after["started"][:n_train] > 0.5
    moving = w_train & (ev_after["speed"][:n_train] > 0.5)
    curv = np.abs(ev_after["curvature"][:n_train][moving])
    speed = ev_after["speed"][:n_train][moving]
    a_tr = ev_after["a"][:n_train]
    return {
        "cmax": float(np.percentile(curv, 99.5)) if curv.size else 0.0,  # robust: isolated windows at a standstill
        "vmax": float(np.percentile(speed, 99.5)) if speed.size else 0.0,
        "refinements": int(np.sum(np.abs(np.diff(a_tr, axis=-1)) > 0)),
        "dmax": float(np.max(ev_after["distance"][:n_train], initial=0.0)),
    }


def identifiability_warnings(param_rows: dict, context: dict, hints: dict) -> list[str]:
    """One warning per parameter reported not identifiable (one line per vector key), with a hint."""
    warnings = []
    vector_done = set()
    for label, row in param_rows.items():
        if row["status"] != "not identifiable":
            continue
        key = label.split("[")[0]
        if "[" in label:  # one line per vector key (the deviation curve)
            if key in vector_done:
                continue
            vector_done.add(key)
            entries = [lb for lb in param_rows if lb.split("[")[0] == key]
            bad = [lb for lb in entries if param_rows[lb]["status"] == "not identifiable"]
            idx = ", ".join(lb[len(key) + 1:-1] for lb in bad)
            warnings.append(f"{key}: {len(bad)} of {len(entries)} entries are not identifiable from these drives "
                            f"(posterior std >= {NOT_IDENTIFIABLE_RATIO} x prior std): [{idx}]; kept at their "
                            f"starting values")
            continue
        why = "the loss does not depend on it with these drives and settings" if not row["data_signal"] else \
            f"posterior std = {row['posterior_to_prior_std']:.2f} x prior std"
        hint = hints.get(key, "").format(**context)
        warnings.append(f"{label} is not identifiable from these drives ({why}); kept at the starting value "
                        f"{row['start']:.6g}" + (f". {hint}" if hint else ""))
    return warnings


def block_correlation(labels: Sequence[str], blocks) -> np.ndarray:
    """The block-diagonal correlation of stages fitted one after the other (NaN across stages)."""
    full = np.full((len(labels), len(labels)), np.nan)
    i0 = 0
    for block in blocks:
        n = block.shape[0]
        full[i0:i0 + n, i0:i0 + n] = block
        i0 += n
    return full


def effective_track_table(start, fitted, c_grid=(0.0, 0.05, 0.1, 0.15, 0.2)) -> dict:
    """T_E at a few curvatures before and after (eq. 14; T_R for rear-axle sensors)."""
    from jaxmodel.track import effective_track

    def te(p):
        if float(p.sensor_axle) < 0.5:
            return [float(p.T_R)] * len(c_grid)
        return [float(v) for v in np.asarray(effective_track(np.asarray(c_grid), p.P, p.B, p.T_F, p.curvature_clip))]

    return {"curvature": list(c_grid), "before_m": te(start), "after_m": te(fitted)}


def json_safe(value):
    """The report with NaN/inf (a drive without compass or reference has no RMSE) as null: strict JSON."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)) and not math.isfinite(float(value)):
        return None
    return value


def zero_start_warnings(report, params_file) -> list[str]:
    """A parameter started at 0, the boundary of a softplus parameter: said, with what it was fitted from."""
    out = []
    for label, row in report.get("parameters", {}).items():
        if row.get("transform") == "softplus":
            out.append(f"{label} starts at 0 in {params_file}, the boundary of a non-negative parameter: fitted as "
                       f"c softplus(u) from {row['start']:.4g} (identification.loss); fitted {row['fitted']:.6g}")
    return out
