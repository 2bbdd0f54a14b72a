"""The real-data experiments of docs/real-data.md: every figure and number on that page, from the
two real logs in ``../shared/data/real/`` converted by ``identification.importers``.

    .venv/bin/python -m identification.real_data experiments [--real-dir ../shared/data/real]
         [--out build/real-data] [--img docs/img] [--max-iter 300]

(``python -m identification.importers experiments`` still runs it.)  Split from the importers
(issue 11): the importers convert logs for ``odocompass import``; this module estimates and
identifies on the converted drives and writes the documentation's figures.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .importers import (COMMA_MAG_AXES, HUSKY_WIDE_TR_PRIOR, RAV4, SF_2018, _interp_angle_deg, _load_comma,
                        comma2k19_params, comma_pose, course_scale_fit, gps_course_check, heading_rmse_deg,
                        husky_params, import_comma2k19, import_husky, level, split_drive, wrap_deg)


def _flat(params_json: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in params_json.items() if k != "report"}


def comma_hard_iron_offsets(columns, until_s: float) -> tuple[float, float]:
    """One-heading hard-iron estimate (X0, Y0) from samples with time_s < until_s: the mean of the
    measured horizontal field minus the WMM field expected at the *reference* heading.

    Uses the reference, so it is a calibration for a demonstration on the remaining samples, not
    an independent compass check (one heading cannot separate an offset from a heading error).
    """
    t = np.asarray(columns["time_s"])
    sel = t < until_s
    psi_m = np.deg2rad(columns["ref_heading_deg"][sel] - SF_2018["declination_deg"])
    h = SF_2018["horizontal_uT"]
    x0 = float(np.mean(columns["compass_x"][sel] - h * np.cos(psi_m)))
    y0 = float(np.mean(columns["compass_y"][sel] - h * np.sin(psi_m)))
    return x0, y0


_COMMA_MODES = ("compass", "odometer", "complementary")


def _comma_modes(pjson: dict[str, Any], drive) -> dict[str, dict]:
    """The estimator's outputs on ``drive`` in each heading mode, with the parameter file ``pjson``."""
    import jaxmodel
    from .estimate import estimate_drive

    params = jaxmodel.make_params(_flat(pjson))
    return {m: estimate_drive(params, drive, jaxmodel.Config(mode=m)) for m in _COMMA_MODES}


def _heading_change_error_end(wheel, ref) -> float:
    """The wheel heading's change over the whole drive minus the reference's [deg, rounded]."""
    return round(float(wrap_deg((wheel[-1] - wheel[0]) - (ref[-1] - ref[0]))), 2)


def _comma_uncalibrated(raw: dict, ref) -> dict[str, Any]:
    """Numbers of the uncalibrated run (X0 = Y0 = 0): each mode's RMSE and mean error against the pose, the
    front-pair odometer's heading-change error and its final dpp_ratio."""
    wheel = raw["odometer"]["wheel_heading_deg"]
    rel = wrap_deg((wheel - wheel[0]) - (ref - ref[0]))
    return {
        "uncalibrated_rmse_deg": {m: round(heading_rmse_deg(o["heading_deg"], ref), 2) for m, o in raw.items()},
        "uncalibrated_mean_error_deg": {m: round(float(np.mean(wrap_deg(o["heading_deg"] - ref))), 2)
                                        for m, o in raw.items()},
        "odometer_heading_change_error_deg": {"rms": round(float(np.sqrt(np.mean(rel ** 2))), 2),
                                              "max_abs": round(float(np.max(np.abs(rel))), 2),
                                              "end": round(float(rel[-1]), 2)},
        "dpp_ratio_end": float(raw["odometer"]["dpp_ratio"][-1])}


def _comma_axle_pairs(real_dir: Path, pjson: dict[str, Any], drive, ref) -> dict[str, Any]:
    """The rear pair for comparison (the reason for the front default): the odometer's heading-change error
    at the end from the rear wheels (calibration on and off) and from the front wheels (calibration off)."""
    import jaxmodel
    from .drive_log import drive_from_columns
    from .estimate import estimate_drive

    rear_cols, rear_rep = import_comma2k19(Path(real_dir) / "comma2k19_example", axle="rear")
    rear_params = jaxmodel.make_params(_flat(comma2k19_params(rear_rep)))
    rear_drive = drive_from_columns(rear_cols, source="comma2k19 rear")
    rear = {}
    for cal in (True, False):
        o = estimate_drive(rear_params, rear_drive, jaxmodel.Config(mode="odometer", calibration=cal))
        rear["calibration_on" if cal else "calibration_off"] = _heading_change_error_end(o["wheel_heading_deg"], ref)
    front = estimate_drive(jaxmodel.make_params(_flat(pjson)), drive,
                           jaxmodel.Config(mode="odometer", calibration=False))
    return {"rear_pair_heading_change_error_end_deg": rear,
            "front_pair_heading_change_error_end_deg_calibration_off":
                _heading_change_error_end(front["wheel_heading_deg"], ref)}


class _HardIron(NamedTuple):
    """The hard-iron calibration of the comma2k19 drive and what it gives."""
    pjson: dict[str, Any]         # the parameter file with X0, Y0
    outs: dict[str, dict]         # the estimator's outputs per mode with it
    half: float                   # X0, Y0 from time_s < half, evaluated after it [s]
    results: dict[str, Any]       # the offsets and each mode's RMSE on the second half


def _comma_hard_iron(columns, pjson: dict[str, Any], drive) -> _HardIron:
    """Hard-iron offsets from the first half (with the reference), evaluated on the second half."""
    t = np.asarray(columns["time_s"])
    ref = columns["ref_heading_deg"]
    half = 0.5 * float(t[-1])
    x0, y0 = comma_hard_iron_offsets(columns, half)
    cal_json = dict(pjson, X0=x0, Y0=y0)
    cal = _comma_modes(cal_json, drive)
    second = t >= half
    results = {"hard_iron_offsets_uT": {"X0": round(x0, 2), "Y0": round(y0, 2), "from_s": [0.0, round(half, 1)]},
               "calibrated_rmse_second_half_deg": {
                   m: round(heading_rmse_deg(o["heading_deg"][second], ref[second]), 2) for m, o in cal.items()}}
    return _HardIron(cal_json, cal, half, results)


def _comma_headings_figure(path: Path, columns, raw: dict, hard_iron: _HardIron) -> None:
    """comma2k19_headings.png: the headings, then each mode's error against the pose without and with
    the hard-iron offsets."""
    from .plots import pyplot, save_figure

    t = np.asarray(columns["time_s"])
    ref = columns["ref_heading_deg"]
    wheel = raw["odometer"]["wheel_heading_deg"]
    half = hard_iron.half
    fig, ax = pyplot().subplots(3, 1, figsize=(9, 9), sharex=True)
    ax[0].plot(t, ref, label="reference (pose, camera axis)")
    ax[0].plot(t, columns["vel_heading_deg"], label="pose velocity direction")
    ax[0].plot(t, ref[0] + wrap_deg(wheel - wheel[0]), label="odometer (front pair), started at the reference")
    ax[0].set_ylabel("heading [deg]")
    ax[0].legend(fontsize=8)
    ax[0].set_title("comma2k19 RAV4 segment: headings")
    for m in _COMMA_MODES:
        ax[1].plot(t, wrap_deg(raw[m]["heading_deg"] - ref), label=f"{m} (X0 = Y0 = 0)")
    ax[1].set_ylabel("error vs pose [deg]")
    ax[1].legend(fontsize=8)
    for m in _COMMA_MODES:
        ax[2].plot(t, wrap_deg(hard_iron.outs[m]["heading_deg"] - ref), label=f"{m} (X0, Y0 from 0-{half:.0f} s)")
    ax[2].axvspan(0.0, half, color="0.9", label="offset estimation span")
    ax[2].set_ylabel("error vs pose [deg]")
    ax[2].set_xlabel("time [s]")
    ax[2].legend(fontsize=8)
    save_figure(fig, path, dpi=90)


class _Levelling(NamedTuple):
    """The comma2k19 magnetometer's heading offset from the pose, levelled three ways."""
    t: np.ndarray                 # magnetometer sample times [s]
    pitch: np.ndarray             # the pose's pitch and roll there [rad]
    roll: np.ndarray
    offsets: dict[str, tuple[np.ndarray, float]]   # variant: (magnetic heading - reference [deg],
                                                   # its slope against pitch [deg/deg])


def _comma_levelling(real_dir: Path) -> _Levelling:
    """Levelling evidence: the compass offset against the road's pitch with z up (used), z down (the
    README's axes) and not levelled."""
    arr = _load_comma(Path(real_dir) / "comma2k19_example")
    pose = comma_pose(arr)
    tm = arr["mag_t"]
    pitch = np.interp(tm, pose["t"], pose["pitch"])
    roll = np.interp(tm, pose["t"], pose["roll"])
    refm = _interp_angle_deg(tm, pose["t"], pose["heading"])
    variants = {"levelled, z up (used)": level(arr["mag_v"] @ COMMA_MAG_AXES.T, pitch, roll),
                "levelled, z down (README axes)": level(arr["mag_v"], pitch, roll),
                "not levelled": arr["mag_v"]}
    offsets = {}
    for name, v in variants.items():
        off = wrap_deg(np.rad2deg(np.arctan2(-v[:, 1], v[:, 0])) - refm)
        offsets[name] = (off, float(np.polyfit(np.rad2deg(pitch), off, 1)[0]))
    return _Levelling(tm, pitch, roll, offsets)


def _comma_levelling_figure(path: Path, lev: _Levelling) -> None:
    """comma2k19_levelling.png: each variant's offset (minus its mean), then the pose's pitch and roll."""
    from .plots import pyplot, save_figure

    tm = lev.t
    fig, ax = pyplot().subplots(2, 1, figsize=(9, 6), sharex=True)
    for name, (off, slope) in lev.offsets.items():
        ax[0].plot(tm - tm[0], off - np.mean(off), label=f"{name}: std {np.std(off):.2f}°, {slope:+.2f}°/° pitch")
    ax[0].set_ylabel("magnetic heading - reference\n(minus its mean) [deg]")
    ax[0].legend(fontsize=8)
    ax[0].set_title("comma2k19 magnetometer: which z sign levels the compass")
    ax[1].plot(tm - tm[0], np.rad2deg(lev.pitch), label="pitch (pose)")
    ax[1].plot(tm - tm[0], np.rad2deg(lev.roll), label="roll (pose)")
    ax[1].set_ylabel("[deg]")
    ax[1].set_xlabel("time [s]")
    ax[1].legend(fontsize=8)
    save_figure(fig, path, dpi=90)


def run_comma_experiment(real_dir: Path, out_dir: Path, img_dir: Path) -> dict[str, Any]:
    """The comma2k19 experiment of docs/real-data.md: the three heading modes on the RAV4 segment without
    and with hard-iron offsets, the rear wheel pair for comparison, and the magnetometer's levelling;
    writes the two parameter files and the two figures, returns the numbers."""
    from .drive_log import drive_from_columns

    columns, report = import_comma2k19(Path(real_dir) / "comma2k19_example")
    pjson = comma2k19_params(report)
    drive = drive_from_columns(columns, source="comma2k19")
    ref = columns["ref_heading_deg"]
    raw = _comma_modes(pjson, drive)
    res: dict[str, Any] = {"import": report, **_comma_uncalibrated(raw, ref),
                           **_comma_axle_pairs(real_dir, pjson, drive, ref)}
    hard_iron = _comma_hard_iron(columns, pjson, drive)
    res.update(hard_iron.results)

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "comma2k19.params.json").write_text(json.dumps(pjson, indent=2) + "\n")
    (out_dir / "comma2k19.calibrated.params.json").write_text(json.dumps(hard_iron.pjson, indent=2) + "\n")
    _comma_headings_figure(img_dir / "comma2k19_headings.png", columns, raw, hard_iron)
    lev = _comma_levelling(real_dir)
    res["levelling"] = {name: {"std_deg": round(float(np.std(off)), 2), "slope_deg_per_deg_pitch": round(slope, 2)}
                        for name, (off, slope) in lev.offsets.items()}
    _comma_levelling_figure(img_dir / "comma2k19_levelling.png", lev)
    return res


class _GpsFixes(NamedTuple):
    """The Husky's valid GPS fixes (local east/north) and the controller's odometry yaw they are checked with."""
    t: np.ndarray
    east: np.ndarray
    north: np.ndarray
    t_all: np.ndarray             # every sample's time
    odo_yaw: np.ndarray           # controller odometry yaw at t_all [rad, unwrapped]


def _gps_fixes(columns) -> _GpsFixes:
    """The valid fixes of an imported Husky drive's columns."""
    t_all = np.asarray(columns["time_s"])
    fv = np.asarray(columns["fix_valid"]) > 0
    fix_t, fe, fn = t_all[fv], np.asarray(columns["fix_east_m"])[fv], np.asarray(columns["fix_north_m"])[fv]
    odo_yaw = -np.unwrap(np.deg2rad(columns["odom_heading_deg"]))
    return _GpsFixes(fix_t, fe, fn, t_all, odo_yaw)


def _husky_fits(train, val, nominal, config, max_iter: int, out_dir: Path, report: dict) -> tuple[dict, dict]:
    """(variants, results): T_R and a identified on ``train`` with the default and the wide T_R prior, each
    fit's summary, and its parameter file written to ``out_dir``."""
    import time

    import jaxmodel
    from .identify import identify

    variants, results = {}, {}
    fits = {"identified": None, "identified_wide_T_R_prior": {"T_R": HUSKY_WIDE_TR_PRIOR}}
    for name, prior in fits.items():
        t0 = time.perf_counter()
        fitted, fit_report = identify([train], nominal, fit=("T_R", "a"), validate_drives=[val], mode="odometer",
                                      max_iter=max_iter, progress=sys.stderr.isatty(), config=config,
                                      prior_std=prior)
        variants[name] = (fitted, fit_report)
        results[name] = {
            "prior_std_log_T_R": (prior or {}).get("T_R", 0.05), "wall_s": round(time.perf_counter() - t0, 1),
            "T_R": float(fitted.T_R), "a": float(fitted.a),
            "T_R_std_error": fit_report["parameters"]["T_R"]["std_error"],
            "T_R_status": fit_report["parameters"]["T_R"]["status"],
            "a_status": fit_report["parameters"]["a"]["status"],
            "iterations": fit_report["iterations"], "warnings": fit_report["warnings"],
            "drives": fit_report["drives"]}
        out_dir.mkdir(parents=True, exist_ok=True)
        jaxmodel.save_params(out_dir / f"husky.{name}.params.json", fitted,
                             report={"identify": fit_report, "import": report})
    return variants, results


def _husky_rmse(variants: dict, train, val, config) -> tuple[dict, dict]:
    """(rows, outs): each variant's odometer heading RMSE and final error against the IMU yaw on the train
    and validate parts, and the estimator's outputs there."""
    from .estimate import estimate_drive

    rows: dict[str, dict[str, float]] = {}
    outs = {}
    for name, (params, _rep) in variants.items():
        for part, d in (("train", train), ("validate", val)):
            o = estimate_drive(params, d, config)
            outs[(name, part)] = o
            ref = np.rad2deg(d.ref_heading)
            rows.setdefault(name, {})[part] = round(heading_rmse_deg(o["heading_deg"], ref), 2)
            e = wrap_deg(o["heading_deg"] - ref)
            rows[name][f"{part}_final_error"] = round(float(e[-1]), 2)
    return rows, outs


def _husky_gps_check(gps: _GpsFixes, val, variants: dict, outs: dict) -> dict:
    """Independent check: GPS course over ground on straight stretches of the validation part."""
    tv = np.asarray(val.inputs.time_s)
    in_val = gps.t >= tv[0]
    fix = (gps.t[in_val], gps.east[in_val], gps.north[in_val], gps.t_all, gps.odo_yaw)
    checks = {"imu_reference": gps_course_check(tv, np.rad2deg(val.ref_heading), *fix)}
    for name in variants:
        checks[f"odometer_{name}"] = gps_course_check(tv, outs[(name, "validate")]["heading_deg"], *fix)
    return checks


def _husky_course_scales(gps: _GpsFixes, columns, drive, variants: dict, config) -> dict:
    """Whole drive: which scale of each heading's turn angles fits the GPS course (block bootstrap CI)."""
    from .estimate import estimate_drive

    sources = {"imu_reference": np.rad2deg(drive.ref_heading), "controller_odometry": columns["odom_heading_deg"],
               "imu_gyro_integral": columns["gyro_heading_deg"]}
    for name, (params, _rep) in variants.items():
        sources[f"odometer_{name}"] = estimate_drive(params, drive, config)["heading_deg"]
    return {name: course_scale_fit(gps.t_all, h_deg, gps.t, gps.east, gps.north, gps.t_all, gps.odo_yaw,
                                   bootstrap=200)
            for name, h_deg in sources.items()}


_HUSKY_COLORS = {"nominal": "C0", "identified": "C3", "identified_wide_T_R_prior": "C2"}
_HUSKY_LABELS = {"nominal": "nominal", "identified": "identified (T_R prior 5 %)",
                 "identified_wide_T_R_prior": f"identified (T_R prior {HUSKY_WIDE_TR_PRIOR:.0%})"}


def _unwrap_deg(a):
    """Angles in degrees, unwrapped."""
    return np.rad2deg(np.unwrap(np.deg2rad(a)))


def _plot_husky_headings(ax, drive, variants: dict, config, gps: _GpsFixes) -> None:
    """The whole drive's headings, unwrapped: IMU yaw, each variant's odometer, the GPS course."""
    from .estimate import estimate_drive

    t = gps.t_all
    ref = np.rad2deg(drive.ref_heading)
    ax.plot(t, _unwrap_deg(ref), color="k", lw=1.5, label="IMU yaw (reference)")
    for name, (params, _rep) in variants.items():
        o = estimate_drive(params, drive, config)
        ax.plot(t, _unwrap_deg(o["heading_deg"]), color=_HUSKY_COLORS[name], lw=1,
                label=f"odometer, {_HUSKY_LABELS[name]}: T_R = {float(params.T_R):.3f} m")
    span = 15
    fix_t, fe, fn = gps.t, gps.east, gps.north
    de, dn = fe[span:] - fe[:-span], fn[span:] - fn[:-span]
    tc = 0.5 * (fix_t[span:] + fix_t[:-span])
    ok = np.hypot(de, dn) >= 0.4 * (fix_t[span:] - fix_t[:-span])
    course = np.rad2deg(np.arctan2(de, dn))[ok]
    near = np.interp(tc[ok], t, _unwrap_deg(ref))
    ax.plot(tc[ok], near + wrap_deg(course - near), ".", ms=2.5, color="0.55",
            label="GPS course over ground (6 s baseline)")


def _plot_husky_errors(ax, variants: dict, outs: dict, rows: dict, train, val, train_fraction: float) -> None:
    """Each variant's odometer error against the IMU yaw, the train part faded (restarted at the split)."""
    for name in variants:
        for part, d, alpha in (("train", train, 0.45), ("validate", val, 1.0)):
            o = outs[(name, part)]
            lab = (f"{_HUSKY_LABELS[name]}: RMSE {rows[name]['train']:.2f}° (first {train_fraction:.0%}), "
                   f"{rows[name]['validate']:.2f}° (last {1 - train_fraction:.0%})") if part == "validate" else None
            ax.plot(np.asarray(d.inputs.time_s), wrap_deg(o["heading_deg"] - np.rad2deg(d.ref_heading)),
                    color=_HUSKY_COLORS[name], alpha=alpha, lw=1, label=lab)


def _husky_figure(path: Path, drive, train, val, variants: dict, outs: dict, rows: dict, gps: _GpsFixes, config,
                  train_fraction: float) -> None:
    """husky_identification.png: headings over the whole drive, and the odometer errors."""
    from .plots import pyplot, save_figure

    plt = pyplot()
    fig, ax = plt.subplots(2, 1, figsize=(10, 8.5), sharex=True)
    _plot_husky_headings(ax[0], drive, variants, config, gps)
    for a_ in ax:
        a_.axvline(float(np.asarray(val.inputs.time_s)[0]), color="0.3", lw=1, ls=":")
    ax[0].set_ylabel("heading [deg, unwrapped]")
    ax[0].set_title(f"Husky test1.bag: T_R and a identified on the first {train_fraction:.0%} "
                    f"(left of the dotted line)")
    ax[0].legend(fontsize=7, loc="upper left")
    _plot_husky_errors(ax[1], variants, outs, rows, train, val, train_fraction)
    ax[1].set_ylabel("odometer - IMU yaw [deg]\n(restarted at the split)")
    ax[1].set_xlabel("time [s]")
    ax[1].legend(fontsize=8)
    save_figure(fig, path, dpi=90)


def run_husky_experiment(real_dir: Path, out_dir: Path, img_dir: Path, max_iter: int = 300,
                         train_fraction: float = 0.6) -> dict[str, Any]:
    """The Husky experiment of docs/real-data.md: T_R and a identified on the first ``train_fraction`` of
    test1.bag (default and wide T_R prior), checked against the IMU yaw on the rest and against the GPS
    course; writes the parameter files and husky_identification.png, returns the numbers."""
    import jaxmodel
    from .drive_log import drive_from_columns

    bag = Path(real_dir) / "husky_test1" / "test1.bag"
    columns, report = import_husky(bag)
    pjson = husky_params(report)
    nominal = jaxmodel.make_params(_flat(pjson))
    drive = drive_from_columns(columns, source=str(bag))
    train, val = split_drive(drive, train_fraction)
    res: dict[str, Any] = {"import": report, "train_s": round(train.metadata["duration_s"], 1),
                           "validate_s": round(val.metadata["duration_s"], 1)}

    # One configuration for the fits and for every figure below: odometer heading, online refinement
    # of a on (its gates - 15-45 mph - never open at the Husky's <= 1 m/s), left/right calibration
    # off (the identification's default; on this drive it leaves dpp_ratio at 1.0 anyway).
    config = jaxmodel.Config(mode="odometer", refine_a=True, calibration=False)
    fits, res["fits"] = _husky_fits(train, val, nominal, config, max_iter, out_dir, report)
    variants = {"nominal": (nominal, None), **fits}
    res["nominal"] = {"T_R": float(nominal.T_R), "a": float(nominal.a)}
    rows, outs = _husky_rmse(variants, train, val, config)
    res["odometer_rmse_vs_imu_deg"] = rows
    gps = _gps_fixes(columns)
    res["gps_course_check_validate"] = _husky_gps_check(gps, val, variants, outs)
    res["gps_course_scale_fit_whole_drive"] = _husky_course_scales(gps, columns, drive, variants, config)
    (out_dir / "husky.params.json").write_text(json.dumps(pjson, indent=2) + "\n")
    _husky_figure(img_dir / "husky_identification.png", drive, train, val, variants, outs, rows, gps, config,
                  train_fraction)
    return res


def _experiments_main(argv=None) -> int:
    import argparse

    import jax

    jax.config.update("jax_enable_x64", True)
    p = argparse.ArgumentParser(prog="python -m identification.real_data",
                                description="real-data experiments of docs/real-data.md")
    p.add_argument("what", choices=("experiments", "comma2k19", "husky"))
    here = Path(__file__).resolve().parents[1]
    p.add_argument("--real-dir", default=str(here.parent / "shared" / "data" / "real"))
    p.add_argument("--out", default=str(here / "build" / "real-data"))
    p.add_argument("--img", default=str(here / "docs" / "img"))
    p.add_argument("--max-iter", type=int, default=300)
    a = p.parse_args(argv)
    results = {}
    if a.what in ("experiments", "comma2k19"):
        results["comma2k19"] = run_comma_experiment(Path(a.real_dir), Path(a.out), Path(a.img))
    if a.what in ("experiments", "husky"):
        results["husky"] = run_husky_experiment(Path(a.real_dir), Path(a.out), Path(a.img), max_iter=a.max_iter)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / f"{a.what}-results.json").write_text(json.dumps(results, indent=2, default=float) + "\n")
    print(json.dumps(results, indent=2, default=float))
    return 0


main = _experiments_main

if __name__ == "__main__":
    sys.exit(_experiments_main())
