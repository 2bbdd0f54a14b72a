"""``odocompass fleet identify MANIFEST --params INIT.json --out DIR``: ``identify`` for every
vehicle of a manifest, on Ray (docs/fleet.md).

Flow:

1. Checks before any work (exit 2, one line): the manifest (fleet_manifest), the start file, the
   fit set, ``--out`` (a writable folder, no output over an input).
2. Resume: a vehicle whose ``DIR/<vehicle_id>.json`` holds a finished fit (status ok or warning)
   with the same fingerprint (start parameters, fit set, options, each drive's path, size and
   modification time) is skipped; errors are always retried.
3. The other vehicles are sorted by the size of their logs (similar lengths share a compiled
   program) and cut into tasks of ``--batch`` vehicles.  A task (one CPU, one XLA thread) reads
   its drives (a missing, corrupt or bad log, or one without reference heading, marks that
   vehicle ``error`` and the rest go on), groups the vehicles by length bucket and fits each
   group in one vmapped program (fleet_fit.fit_group).  If a group's batched fit fails, its
   vehicles are fitted one by one so that only the culprit ends ``error``.
4. Each vehicle's parameter file (with its report, usable by ``estimate`` and ``build-fmu``) is
   written atomically as soon as its task returns, so an interrupted fleet resumes where it was.
5. At the end: ``DIR/summary.csv`` and ``DIR/summary.parquet`` (one row per manifest vehicle),
   ``DIR/parameters.png`` (the fleet's distributions), one summary line.  Exit 0 when every
   vehicle ended ``ok`` or ``warning``, 3 when some ended ``error`` (EXIT_SOME_FAILED).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import fleet_ray
from .fleet_manifest import ManifestVehicle, fingerprint, read_manifest

EXIT_SOME_FAILED = 3
DEFAULT_BATCH = 8


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _read_vehicle(vid: str, train: list, validate: list):
    """(VehicleData, None) or (None, error line) for one vehicle's logs."""
    from .drive_log import read_drive
    from .fleet_fit import VehicleData

    if not train:
        return None, "no training drive (role train) in the manifest"
    drives = {"train": [], "validate": []}
    for role, paths in (("train", train), ("validate", validate)):
        for p in paths:
            try:
                d = read_drive(p)
            except FileNotFoundError:
                return None, f"{p}: drive log not found"
            except Exception as exc:  # noqa: BLE001 - DriveLogError, OSError, a corrupt Parquet/MDF4
                text = _one_line(exc)
                return None, text if str(p) in text else f"{p}: {text}"
            if d.ref_heading is None or not np.any(np.isfinite(d.ref_heading)):
                return None, f"{p}: no reference heading (column 'ref_heading_deg'), which identification needs"
            if d.n_samples < 2:
                return None, f"{p}: only {d.n_samples} sample(s); identification needs a drive"
            drives[role].append(d)
    return VehicleData(vid, drives["train"], drives["validate"]), None


def identify_task(payload: dict) -> list[dict]:
    """A Ray task: read, group by length bucket, fit; one result dict per vehicle (never raises for
    a vehicle's problem)."""
    fleet_ray.worker_setup()
    import jaxmodel

    from .fleet_fit import FitOptions, bucket_length, fit_group

    t0 = time.perf_counter()
    start = jaxmodel.make_params(payload["start"])
    options = FitOptions(**payload["options"])
    keys = payload["keys"]
    results, ready = [], []
    for vid, train, validate in payload["vehicles"]:
        veh, err = _read_vehicle(vid, train, validate)
        if err:
            results.append(dict(vehicle_id=vid, status="error", params=None, report=None, error=err))
        else:
            ready.append(veh)
    groups: dict[tuple, list] = {}
    for veh in ready:
        n = bucket_length(max(d.n_samples for d in veh.train))
        groups.setdefault((n, len(veh.train)), []).append(veh)
    for _, vehs in sorted(groups.items()):
        try:
            pad = max(0, payload.get("pad_to", 0) - len(vehs)) if len(vehs) > 1 else 0
            active = np.array([True] * len(vehs) + [False] * pad)
            out = fit_group(vehs + [vehs[0]] * pad, start, keys, options, active=active)
        except Exception:  # noqa: BLE001 - isolate the vehicle that breaks the batch
            out = []
            for veh in vehs:
                try:
                    out += fit_group([veh], start, keys, options)
                except Exception as exc:  # noqa: BLE001 - this vehicle alone fails: its error, the rest go on
                    out.append(dict(vehicle_id=veh.vehicle_id, status="error", params=None, report=None,
                                    error=f"identification failed: {type(exc).__name__}: {_one_line(exc)[:300]}"))
        for r in out:
            r.pop("fitted", None)
            results.append(r)
    wall = time.perf_counter() - t0
    for r in results:
        r["task_wall_s"] = wall
        r["task_vehicles"] = len(payload["vehicles"])
    return results


# ----------------------------------------------------------------------------------------------
# the driver


def _settings(start_dict: dict, keys, options: dict) -> dict:
    return {"start": start_dict, "fit": list(keys), "options": options}


def _finished(path: Path, fp: str) -> dict | None:
    """The report of a finished fit at ``path`` with fingerprint ``fp``, else None."""
    import jaxmodel

    if not path.is_file():
        return None
    try:
        _params, extra = jaxmodel.load_params(path)
    except Exception:  # noqa: BLE001 - a damaged result is simply redone
        return None
    report = extra.get("report") or {}
    fleet = report.get("fleet") or {}
    if fleet.get("fingerprint") == fp and fleet.get("status") in ("ok", "warning"):
        return report
    return None


def _rms(rows: list[dict], role: str, key: str) -> float:
    vals = [(r.get(key), r.get("n_samples", 1)) for r in rows if r.get("role") == role]
    vals = [(v, n) for v, n in vals if v is not None and math.isfinite(v)]
    if not vals:
        return float("nan")
    return float(math.sqrt(sum(v * v * n for v, n in vals) / sum(n for _, n in vals)))


def summary_row(vid: str, status: str, report: dict | None, error: str | None, n_train: int, n_validate: int,
                labels: list[str], resumed: bool = False) -> dict[str, Any]:
    """One summary row: status, each fitted parameter and its standard error, RMSE before/after
    (train and validate drives, sample-weighted RMS over the drives), warnings or the error."""
    row: dict[str, Any] = {"vehicle_id": vid, "status": status, "n_train": n_train, "n_validate": n_validate}
    params = (report or {}).get("parameters", {})
    for label in labels:
        p = params.get(label) or {}
        row[label] = p.get("fitted", float("nan"))
        row[f"{label}_std_error"] = p.get("std_error", float("nan"))
    rows = (report or {}).get("drives", [])
    for role in ("train", "validate"):
        for tag in ("before", "after"):
            row[f"{role}_rmse_{tag}_deg"] = _rms(rows, role, f"rmse_{tag}_deg")
    row["iterations"] = (report or {}).get("iterations", 0)
    row["resumed"] = bool(resumed)
    row["warnings"] = " | ".join((report or {}).get("warnings", []))
    row["error"] = error or ""
    for k, v in row.items():
        if v is None:
            row[k] = float("nan")
    return row


def write_summary(out_dir: Path, rows: list[dict]) -> list[Path]:
    """summary.csv and summary.parquet, written together (outputs.staged)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    from .outputs import staged

    columns = list(rows[0]) if rows else ["vehicle_id", "status", "error"]
    table = pa.table({c: [r.get(c) for r in rows] for c in columns})
    paths = [out_dir / "summary.csv", out_dir / "summary.parquet"]
    with staged(paths) as (tmp_csv, tmp_pq):
        pacsv.write_csv(table, tmp_csv)
        pq.write_table(table, tmp_pq)
    return paths


def write_distribution_plot(path: Path, rows: list[dict], labels: list[str], start: dict) -> Path | None:
    """Histograms of each fitted parameter over the vehicles that finished, start value marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .outputs import atomic

    good = [r for r in rows if r["status"] in ("ok", "warning")]
    if not good or not labels:
        return None
    n = len(labels)
    cols = min(n, 4)
    nrows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(3.6 * cols, 2.8 * nrows), squeeze=False)
    for ax, label in zip(axes.ravel(), labels):
        vals = np.array([r[label] for r in good], dtype=float)
        vals = vals[np.isfinite(vals)]
        ax.hist(vals, bins=min(30, max(5, vals.size // 4)), color="tab:blue", alpha=0.8)
        s = start.get(label.split("[")[0])
        if isinstance(s, (int, float)):
            ax.axvline(float(s), color="tab:red", lw=1, label="start")
        ax.set_title(f"{label} (n={vals.size})", fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(f"fitted parameters of {len(good)} vehicles (red: start file)", fontsize=10)
    fig.tight_layout()
    with atomic(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path


@dataclass
class _Fleet:
    """The driver's run once its inputs are checked (step 1); ``rows`` fills as vehicles finish."""
    manifest: Path
    params_path: str              # the start file as given (--params)
    vehicles: dict[str, ManifestVehicle]
    out_dir: Path
    start_dict: dict
    keys: tuple
    options: dict
    labels: list[str]
    fps: dict[str, str] = field(default_factory=dict)
    rows: dict[str, dict] = field(default_factory=dict)


def _fit_options(args) -> dict:
    """The FitOptions fields the command line sets (part of the fingerprint)."""
    return dict(mode=args.mode, max_iter=args.max_iter, refine_a=args.refine_a == "on",
                calibration=args.calibration == "on", increment_s=float(args.increment_s),
                direction=args.optimizer)


def _checked_inputs(args) -> _Fleet:
    """Step 1: the manifest, the start file, the fit set and ``--out``, checked before any work; creates
    ``--out``."""
    import jaxmodel

    from . import loss as L
    from .diagnostics import checked_params
    from .outputs import check_folder_files, check_output_dir

    manifest = Path(args.manifest)
    vehicles = read_manifest(manifest)
    start, _extra = checked_params(args.params)
    keys = L.parse_fit(args.fit)
    try:
        space = L.make_space(keys, start)
    except Exception as exc:  # noqa: BLE001 - a start value the parameterisation cannot take
        raise type(exc)(f"{args.params}: {exc}") from None
    out_dir = Path(args.out)
    inputs = [("the manifest", manifest), ("the parameter file", args.params)]
    check_output_dir(out_dir, inputs=inputs, label="--out")
    drives = [("the drive log", p) for v in vehicles.values() for p, _ in v.drives]
    check_folder_files(out_dir, ["summary.csv", "summary.parquet", "parameters.png"]
                       + [f"{vid}.json" for vid in vehicles], inputs + drives)
    out_dir.mkdir(parents=True, exist_ok=True)
    return _Fleet(manifest, args.params, vehicles, out_dir, jaxmodel.params_to_dict(start), keys, _fit_options(args),
                  list(space.labels))


def _resume(fleet: _Fleet) -> list[ManifestVehicle]:
    """Step 2: the summary rows of the vehicles already finished with the same fingerprint; the others,
    still to fit."""
    from . import console

    settings = _settings(fleet.start_dict, fleet.keys, fleet.options)
    todo: list[ManifestVehicle] = []
    for vid, veh in fleet.vehicles.items():
        fleet.fps[vid] = fingerprint(veh, settings)
        report = _finished(fleet.out_dir / f"{vid}.json", fleet.fps[vid])
        if report is not None:
            fleet.rows[vid] = summary_row(vid, report["fleet"]["status"], report, None, len(veh.train),
                                          len(veh.validate), fleet.labels, resumed=True)
        else:
            todo.append(veh)
    if fleet.rows:
        console.info(f"resuming: {len(fleet.rows)} of {len(fleet.vehicles)} vehicles already finished in "
                     f"{fleet.out_dir}, skipped")
    return todo


def _save_fit(fleet: _Fleet, vid: str, params: dict, report: dict) -> str | None:
    """Step 4 for a fitted vehicle: its warnings and fleet status into ``report`` and its parameter file
    written; instead the error line when the fitted parameters are not valid."""
    import jaxmodel

    from .report import json_safe, zero_start_warnings

    fitted = jaxmodel.make_params(params)
    try:
        jaxmodel.validate_params(fitted)
    except jaxmodel.ParameterError as exc:
        return f"the fitted parameters are not valid: {_one_line(exc)}"
    report["warnings"] = (report.pop("drive_warnings", []) + zero_start_warnings(report, fleet.params_path)
                          + report["warnings"])
    status = "warning" if report["warnings"] else "ok"
    report["start_file"] = str(fleet.params_path)
    report["fleet"] = {"vehicle_id": vid, "status": status, "fingerprint": fleet.fps[vid],
                       "manifest": str(fleet.manifest), "manifest_rows": fleet.vehicles[vid].rows}
    jaxmodel.save_params(fleet.out_dir / f"{vid}.json", fitted, json_safe(report))
    return None


def _record(fleet: _Fleet, vid: str, status: str, params: dict | None, report: dict | None, error: str | None):
    """A vehicle's result: its parameter file (unless error) and its summary row."""
    from . import console

    veh = fleet.vehicles[vid]
    if status != "error":
        invalid = _save_fit(fleet, vid, params, report)
        if invalid:
            status, error, report = "error", invalid, None
        else:
            status = report["fleet"]["status"]
    if status == "error":
        console.warn(f"vehicle {vid}: error: {error}")
    fleet.rows[vid] = summary_row(vid, status, report, error, len(veh.train), len(veh.validate), fleet.labels)


def _on_result(fleet: _Fleet, payload: dict, result) -> None:
    """A task's results recorded; a task that failed as a whole marks each of its vehicles ``error``."""
    if isinstance(result, BaseException):
        line = fleet_ray.task_error_line(result)
        for vid, _, _ in payload["vehicles"]:
            _record(fleet, vid, "error", None, None, f"task failed: {line}")
        return
    for r in result:
        _record(fleet, r["vehicle_id"], r["status"], r.get("params"), r.get("report"), r.get("error"))


def _fit_on_ray(fleet: _Fleet, todo: list[ManifestVehicle], args) -> float:
    """Step 3: the vehicles to fit, sorted by the size of their logs and cut into tasks of ``--batch``,
    fitted on Ray, each result recorded as it returns; the wall time of the fits."""
    import ray

    from . import console

    batch = max(1, int(args.batch))
    todo.sort(key=lambda v: v.size_hint())
    chunks = [todo[i:i + batch] for i in range(0, len(todo), batch)]
    payloads = [{"vehicles": [(v.vehicle_id, [str(p) for p in v.train], [str(p) for p in v.validate]) for v in c],
                 "start": fleet.start_dict, "keys": list(fleet.keys), "options": fleet.options, "pad_to": batch}
                for c in chunks]
    t_fit = time.perf_counter()
    if payloads:
        with fleet_ray.cluster(args.address, args.workers) as in_flight:
            remote = ray.remote(num_cpus=1, max_retries=fleet_ray.MAX_RETRIES)(identify_task)
            console.status(f"fitting {len(todo)} vehicles in {len(payloads)} tasks of up to {batch} on "
                           f"{in_flight} workers")
            fleet_ray.run_tasks(remote, payloads, in_flight, [len(c) for c in chunks],
                                lambda payload, result: _on_result(fleet, payload, result), "fleet identify",
                                console.progress_enabled())
    return time.perf_counter() - t_fit


def _write_outputs(fleet: _Fleet, ordered: list[dict]) -> tuple[list[Path], Path | None]:
    """Step 5's files: the summary tables and the distribution plot (whose failure is only a warning)."""
    from . import console

    paths = write_summary(fleet.out_dir, ordered)
    try:
        plot = write_distribution_plot(fleet.out_dir / "parameters.png", ordered, fleet.labels, fleet.start_dict)
    except Exception as exc:  # noqa: BLE001 - a plot never loses the fleet's results
        plot = None
        console.warn(f"{fleet.out_dir / 'parameters.png'}: plot not written: {_one_line(exc)}")
    return paths, plot


def main(args) -> int:
    """``odocompass fleet identify`` (see the module docstring)."""
    import ray  # noqa: F401 - imported before any check, as always: a missing Ray fails at once

    from . import console

    t0 = time.perf_counter()
    fleet = _checked_inputs(args)
    todo = _resume(fleet)
    resumed = len(fleet.rows)
    fit_wall = _fit_on_ray(fleet, todo, args)
    ordered = [fleet.rows[vid] for vid in fleet.vehicles]
    paths, plot = _write_outputs(fleet, ordered)
    counts = {s: sum(r["status"] == s for r in ordered) for s in ("ok", "warning", "error")}
    rate = len(todo) / fit_wall * 60.0 if todo and fit_wall > 0 else float("nan")
    console.info(f"fleet identify: {len(ordered)} vehicles: {counts['ok']} ok, {counts['warning']} warning, "
                 f"{counts['error']} error ({resumed} resumed); {len(todo)} fitted in {fit_wall:.1f} s "
                 f"({rate:.1f} vehicles/min), total {time.perf_counter() - t0:.1f} s; wrote {paths[0]}, "
                 f"{paths[1].name}" + (f", {plot.name}" if plot else ""))
    return EXIT_SOME_FAILED if counts["error"] else 0
