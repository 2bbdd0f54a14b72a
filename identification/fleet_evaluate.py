"""``odocompass fleet evaluate MANIFEST --params P.json|DIR --out DIR``: the estimator over every
drive of a manifest, each with its vehicle's parameters, on Ray (docs/fleet.md).

Drives are sorted by size and cut into tasks of ``--batch`` drives; a task reads its drives (a
missing, corrupt or bad log is that drive's ``error``), groups them by length bucket and runs
each group as one ``jit(vmap(run))`` with per-drive parameters (``vmap`` over both the Params and
the Inputs).  ``DIR/metrics.parquet`` gets one row per manifest row:

vehicle_id, path, role, status (ok/error), error, n_samples, duration_s, distance_m (odometer),
rmse_deg (the chosen mode's heading against ref_heading_deg, NaN without a reference),
wheel_rmse_deg (odometer heading), compass_rmse_deg, ref_samples, skipped_compass_samples,
skipped_odometer_samples, final_x_m, final_y_m, params (the parameter file used), dpp_left_m, dpp_right_m and
dpp_source (the distances per pulse run: ``file``, ``compass`` where the file gave none and the drive's compass
found them, ``nominal`` where it could not; identification/wheel_scales.py).

Exit 0 when every drive was estimated, 3 when some ended ``error``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from . import fleet_ray
from .fleet_manifest import read_manifest

EXIT_SOME_FAILED = 3
COLUMNS = ("vehicle_id", "path", "role", "status", "error", "n_samples", "duration_s", "distance_m", "rmse_deg",
           "wheel_rmse_deg", "compass_rmse_deg", "ref_samples", "skipped_compass_samples",
           "skipped_odometer_samples", "final_x_m", "final_y_m", "params", "dpp_left_m", "dpp_right_m", "dpp_source")
_TEXT_COLUMNS = ("error", "params", "dpp_source")

_CACHE: dict = {}


def _runner(config):
    """jit(vmap over drives of run, with per-drive parameters), cached per worker process."""
    import jax

    import jaxmodel

    if config not in _CACHE:
        _CACHE[config] = jax.jit(jax.vmap(
            lambda p, inp: jaxmodel.run_from(p, jaxmodel.init_state(p), inp, config)[1]))
    return _CACHE[config]


def _rmse(err: np.ndarray, w: np.ndarray) -> float:
    if not np.any(w):
        return float("nan")
    e = np.angle(np.exp(1j * err[w]))
    return float(np.degrees(np.sqrt(np.mean(e * e))))


def _metrics(d, out, b: int) -> dict[str, Any]:
    n = d.n_samples
    t = np.asarray(d.inputs.time_s, dtype=np.float64)
    sl = (b, slice(0, n))
    fields = {k: np.asarray(getattr(out, k))[sl] for k in ("heading", "wheel_heading", "compass_heading", "distance",
                                                          "compass_valid", "odometer_valid", "initialized", "x", "y")}
    bad = [k for k, v in fields.items() if not np.all(np.isfinite(v))]
    if bad:
        raise FloatingPointError(f"the estimator produced non-finite {', '.join(bad)} (a defect in jaxmodel)")
    ref = None if d.ref_heading is None else np.asarray(d.ref_heading, dtype=np.float64)
    started = fields["initialized"] > 0.5
    w = started & np.isfinite(ref) if ref is not None else np.zeros(n, dtype=bool)
    r = np.where(w, ref, 0.0) if ref is not None else np.zeros(n)
    return {
        "n_samples": n, "duration_s": float(t[-1] - t[0]), "distance_m": float(fields["distance"][-1]),
        "rmse_deg": _rmse(fields["heading"] - r, w), "wheel_rmse_deg": _rmse(fields["wheel_heading"] - r, w),
        "compass_rmse_deg": _rmse(fields["compass_heading"] - r, w & (fields["compass_valid"] > 0.5)),
        "ref_samples": int(w.sum()),
        "skipped_compass_samples": int(np.count_nonzero(fields["compass_valid"] < 0.5)),
        "skipped_odometer_samples": int(np.count_nonzero(fields["odometer_valid"][1:] < 0.5)),
        "final_x_m": float(fields["x"][-1]), "final_y_m": float(fields["y"][-1]),
    }


def evaluate_task(payload: dict) -> list[dict]:
    """A Ray task: one metrics row per drive of the payload (never raises for a drive's problem)."""
    fleet_ray.worker_setup()
    import jax
    import jax.numpy as jnp

    import jaxmodel

    from . import wheel_scales
    from .drive_log import read_drive, stack_drives
    from .fleet_fit import bucket_length, pad_batch, stacked_params

    config = jaxmodel.Config(**payload["config"])
    rows, ready = [], []
    for item in payload["drives"]:
        row = {"vehicle_id": item["vehicle_id"], "path": item["path"], "role": item["role"],
               "params": item.get("params_file", ""), "status": "ok", "error": ""}
        if item.get("error"):
            row.update(status="error", error=item["error"])
            rows.append(row)
            continue
        try:
            d = read_drive(item["path"])
            if d.n_samples < 2:
                raise ValueError(f"{item['path']}: only {d.n_samples} sample(s)")
            fit_dpp = item.get("fit_dpp", False)
            params, scales = wheel_scales.for_drive(jaxmodel.make_params(item["params"]), fit_dpp, d, config)
            row.update(dpp_left_m=float(params.dpp_left), dpp_right_m=float(params.dpp_right),
                       dpp_source="compass" if scales else ("nominal" if fit_dpp else "file"))
            ready.append((row, d, params))
        except Exception as exc:  # noqa: BLE001 - a missing, corrupt or bad log: this drive's error
            text = " ".join(str(exc).split()) or type(exc).__name__
            if isinstance(exc, FileNotFoundError):
                text = f"{item['path']}: drive log not found"
            row.update(status="error", error=text if item["path"] in text else f"{item['path']}: {text}")
            rows.append(row)
    groups: dict[int, list] = {}
    for entry in ready:
        groups.setdefault(bucket_length(entry[1].n_samples), []).append(entry)
    run = _runner(config)
    for n, entries in sorted(groups.items()):
        inputs, mask = stack_drives([e[1] for e in entries])
        inputs, mask, _ = pad_batch(inputs, mask, np.zeros_like(mask), n)
        try:
            out = jax.device_get(run(stacked_params([e[2] for e in entries]),
                                     jax.tree_util.tree_map(jnp.asarray, inputs)))
        except Exception as exc:  # noqa: BLE001 - the whole group failed: every drive says why
            for row, _d, _p in entries:
                row.update(status="error", error=f"estimation failed: {type(exc).__name__}: {exc}"[:300])
                rows.append(row)
            continue
        for b, (row, d, _p) in enumerate(entries):
            try:
                row.update(_metrics(d, out, b))
            except Exception as exc:  # noqa: BLE001
                row.update(status="error", error=f"{d.path}: {' '.join(str(exc).split())}")
            rows.append(row)
    return rows


def _vehicle_params(params_arg: Path, vehicle_ids) -> dict[str, tuple]:
    """vehicle_id -> (params dict or None, file, error, fit_dpp) from one file or a folder of <vehicle_id>.json; a
    file without the vehicle's parameters runs the nominal vehicle as ``estimate`` does (its turn scale learned), and
    one without dpp_left, dpp_right has them found from each drive's compass (``fit_dpp``, wheel_scales.for_drive)."""
    import jaxmodel

    from . import wheel_scales
    from .diagnostics import estimation_params

    if not params_arg.is_dir():
        p, extra, _ = estimation_params(params_arg)
        d = jaxmodel.params_to_dict(p)
        return {vid: (d, str(params_arg), None, wheel_scales.dpp_unknown(extra["keys"])) for vid in vehicle_ids}
    out = {}
    for vid in vehicle_ids:
        f = params_arg / f"{vid}.json"
        if not f.is_file():
            out[vid] = (None, str(f), f"{f}: no parameter file for vehicle {vid}", False)
            continue
        try:
            p, extra, _ = estimation_params(f)
            out[vid] = (jaxmodel.params_to_dict(p), str(f), None, wheel_scales.dpp_unknown(extra["keys"]))
        except Exception as exc:  # noqa: BLE001 - a bad parameter file: that vehicle's drives are errors
            text = " ".join(str(exc).split())
            out[vid] = (None, str(f), text if str(f) in text else f"{f}: {text}", False)
    return out


def write_metrics(path: Path, rows: list[dict]) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from .outputs import atomic

    table = pa.table({c: [r.get(c, float("nan") if c not in _TEXT_COLUMNS else "") for r in rows]
                      for c in COLUMNS})
    with atomic(path) as tmp:
        pq.write_table(table, tmp)
    return path


def main(args) -> int:
    """``odocompass fleet evaluate`` (see the module docstring)."""
    import ray

    from . import console
    from .outputs import OutputError, check_folder_files, check_output_dir

    t0 = time.perf_counter()
    manifest = Path(args.manifest)
    vehicles = read_manifest(manifest, require_role=False)
    params_arg = Path(args.params)
    if not params_arg.exists():
        raise OutputError(f"{params_arg}: --params: no such parameter file or folder")
    out_dir = Path(args.out)
    check_output_dir(out_dir, inputs=[("the manifest", manifest), ("the parameter file or folder", params_arg)],
                     label="--out")
    check_folder_files(out_dir, ["metrics.parquet"],
                       [("the drive log", p) for veh in vehicles.values() for p, _ in veh.drives])
    per_vehicle = _vehicle_params(params_arg, list(vehicles))
    items = []
    for vid, veh in vehicles.items():
        params, pfile, err, fit_dpp = per_vehicle[vid]
        for p, role in veh.drives:
            items.append({"vehicle_id": vid, "path": str(p), "role": role, "params": params, "params_file": pfile,
                          "fit_dpp": fit_dpp, "error": err, "size": veh.size_hint()})
    order = {(it["vehicle_id"], it["path"]): k for k, it in enumerate(items)}
    items_sorted = sorted(items, key=lambda it: _size(it["path"]))
    batch = max(1, int(args.batch))
    config = dict(mode=args.mode, refine_a=args.refine_a == "on", calibration=args.calibration == "on",
                  track=args.track)
    payloads = [{"drives": items_sorted[i:i + batch], "config": config} for i in range(0, len(items_sorted), batch)]
    rows: list[dict] = []

    def on_result(payload, result):
        if isinstance(result, BaseException):
            line = fleet_ray.task_error_line(result)
            for it in payload["drives"]:
                rows.append({"vehicle_id": it["vehicle_id"], "path": it["path"], "role": it["role"],
                             "params": it["params_file"], "status": "error", "error": f"task failed: {line}"})
            return
        rows.extend(result)

    with fleet_ray.cluster(args.address, args.workers) as in_flight:
        remote = ray.remote(num_cpus=1, max_retries=fleet_ray.MAX_RETRIES)(evaluate_task)
        fleet_ray.run_tasks(remote, payloads, in_flight, [len(p["drives"]) for p in payloads], on_result,
                            "fleet evaluate", console.progress_enabled(), unit="drive")
    rows.sort(key=lambda r: order[(r["vehicle_id"], r["path"])])
    path = write_metrics(out_dir / "metrics.parquet", rows)
    errors = [r for r in rows if r["status"] == "error"]
    for r in errors:
        console.warn(f"vehicle {r['vehicle_id']}: drive {r['path']}: error: {r['error']}")
    rmse = [r["rmse_deg"] for r in rows if r["status"] == "ok" and math.isfinite(r.get("rmse_deg", float("nan")))]
    med = f"median heading RMSE {np.median(rmse):.3f} deg over {len(rmse)} drives with a reference; " if rmse else ""
    console.info(f"fleet evaluate: {len(rows)} drives of {len(vehicles)} vehicles: {len(rows) - len(errors)} ok, "
                 f"{len(errors)} error; {med}{time.perf_counter() - t0:.1f} s; wrote {path}")
    return EXIT_SOME_FAILED if errors else 0


def _size(path: str) -> int:
    try:
        return Path(path).stat().st_size
    except OSError:
        return 0
