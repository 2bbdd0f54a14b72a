"""Evaluation side of an identification: the batch of drives, one compiled forward pass over every
drive (training and validation) before and after the fit, and the per-drive rows of the report:
heading RMSE against ``ref_heading_deg`` where a drive has it, and against the fixes where it has
them (the course of chords of the dead-reckoned track, ``fixes_loss``, and the position RMSE of the
track translated onto its first fixes)."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import fixes_loss as FX
from . import loss as L
from . import report as R


def drive_name(d) -> str:
    return str(d.metadata.get("path", "<columns>")) if getattr(d, "metadata", None) else "<columns>"


def stack(drives):
    """(inputs as jax arrays, ref (batch, N) rad, sample mask, reference mask) of a batch; a drive
    without ``ref_heading_deg`` has reference mask 0 (the fixes reference does not need one)."""
    import jax
    import jax.numpy as jnp

    from .drive_log import stack_drives

    inputs, mask = stack_drives(drives)
    ref = np.zeros_like(mask)
    rmask = np.zeros_like(mask)
    for b, d in enumerate(drives):
        if d.ref_heading is not None:
            r = np.asarray(d.ref_heading, dtype=np.float64)
            ok = np.isfinite(r)
            ref[b, :len(r)] = np.where(ok, r, 0.0)
            rmask[b, :len(r)] = ok
    return jax.tree_util.tree_map(jnp.asarray, inputs), ref, mask, mask * rmask


class Evaluator:
    """One compiled forward pass over every drive (train + validation) for RMSEs and plots; with
    ``fixes``, a second pass in the odometer mode for the odometer track's position."""

    FIELDS = ("heading", "wheel_heading", "curvature", "effective_track", "speed", "a", "distance", "x", "y")

    def __init__(self, drives, config, fixes: bool = False):
        import jax

        import jaxmodel

        self.inputs, self.ref, self.sample_mask, self.mask = stack(drives)
        self.config = config
        self._fn = jax.jit(lambda p: L.batch_outputs(p, self.inputs, self.config, self.FIELDS))
        self.fixes = fixes
        if fixes:
            odo = jaxmodel.Config(mode="odometer", refine_a=config.refine_a, calibration=config.calibration,
                                  track=config.track, robust=config.robust)
            self._odo = jax.jit(lambda p: L.batch_outputs(p, self.inputs, odo, ("x", "y")))
            self.chords = FX.make_chords(self.inputs, self.sample_mask)

    def __call__(self, params) -> dict[str, np.ndarray]:
        import jax

        out = jax.device_get(self._fn(params))
        d = {k: np.asarray(v) for k, v in zip(self.FIELDS, out)}
        d["started"] = np.asarray(out[-1])
        d["weight"] = self.mask * (d["started"] > 0.5)
        d["ref"] = self.ref
        d["time_s"] = np.asarray(self.inputs.time_s)
        if self.fixes:
            ox, oy, _ = jax.device_get(self._odo(params))
            d["odometer_x"], d["odometer_y"] = np.asarray(ox), np.asarray(oy)
        return d


def rmse_rows(ev_before, ev_after, drives, roles, mode, evaluator: Evaluator | None = None) -> list[dict]:
    """Per drive: heading RMSE before/after against the reference heading (NaN without one), and
    with ``evaluator.fixes`` the chord course RMSE and the position RMSE against the fixes."""
    rows = []
    primary = "wheel_heading" if mode == "odometer" else "heading"
    est_name = "kalman" if mode == "kalman" else "complementary"
    for b, (d, role) in enumerate(zip(drives, roles)):
        t = np.asarray(d.inputs.time_s)
        row: dict[str, Any] = {"role": role, "name": drive_name(d), "n_samples": int(t.size),
                               "duration_s": float(t[-1] - t[0])}
        for tag, ev in (("before", ev_before), ("after", ev_after)):
            w = ev["weight"][b]
            e_odo = ev["wheel_heading"][b] - ev["ref"][b]
            e_est = ev["heading"][b] - ev["ref"][b]
            row[f"odometer_rmse_{tag}_deg"] = R.rmse_deg(e_odo, w)
            row[f"odometer_rmse_offset_removed_{tag}_deg"] = R.rmse_deg(e_odo, w, align=True)
            row[f"{est_name}_rmse_{tag}_deg"] = R.rmse_deg(e_est, w)
            row[f"rmse_{tag}_deg"] = R.rmse_deg(ev[primary][b] - ev["ref"][b], w)
            if evaluator is not None and evaluator.fixes and evaluator.chords.n_fixes[b] >= 2:
                fx = np.asarray(d.inputs.fix_east_m), np.asarray(d.inputs.fix_north_m), np.asarray(d.inputs.fix_valid)
                n = t.size
                started = ev["started"][b][:n]
                for name, xk, yk in (("odometer", "odometer_x", "odometer_y"), (est_name, "x", "y")):
                    row[f"{name}_position_rmse_{tag}_m"] = FX.position_rmse_m(ev[xk][b][:n], ev[yk][b][:n], *fx,
                                                                              started)
                    row[f"{name}_fix_course_rmse_{tag}_deg"] = FX.chord_course_rmse_deg(
                        ev[xk], ev[yk], ev["started"], evaluator.chords, b)
                prim = "odometer" if mode == "odometer" else est_name
                row[f"fix_course_rmse_{tag}_deg"] = row[f"{prim}_fix_course_rmse_{tag}_deg"]
        rows.append(row)
    return rows
