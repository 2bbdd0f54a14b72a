"""``odocompass demo``: the main job on an embedded default (SPEC §5).

1. simulates a 15-minute mixed drive with magnetic anomalies and estimates its heading in every
   mode (complementary, odometer, compass, kalman), printing RMSEs side by side and plotting the
   heading error against time;
2. identifies the parameters of a simulated vehicle (a few percent off the starting file) from
   two drives, validates on a third, and prints the before/after table;
3. builds the estimator FMU into build/ with the identified parameters and co-simulates it with
   the vehicle FMU in fmpy, plotting estimated against true heading.

Everything lands in ``--out-dir`` (default build/demo/), the FMUs included (``--out-dir``/fmu/);
the folder is checked before any work.  The identification table shows the same figures as the
plot legend (absolute RMSE of the odometer-only heading) and, beside them, the RMSE with each
drive's constant offset removed.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

MODES_SHOWN = ("complementary", "kalman", "odometer", "compass")


def _say(msg: str) -> None:
    print(msg, flush=True)


def heading_rmse_deg(heading_rad, truth_rad, time_s, skip_s=60.0) -> float:
    """RMSE of the wrapped heading error after the first ``skip_s`` seconds, degrees."""
    err = np.angle(np.exp(1j * (np.asarray(heading_rad) - np.asarray(truth_rad))))
    keep = np.asarray(time_s) - time_s[0] >= skip_s
    return float(np.rad2deg(np.sqrt(np.mean(err[keep] ** 2))))


def estimate_modes(out_dir: Path, duration_s: float) -> dict[str, float]:
    import jax
    import jax.numpy as jnp

    import jaxmodel as jm

    from .drive_log import drive_from_columns, write_drive
    from .simulate import simulate, write_truth

    columns, truth = simulate("mixed", duration_s, seed=7, fixes_sigma=4.0)
    drive_path = out_dir / "mixed_drive.csv"
    write_drive(drive_path, columns)
    write_truth(drive_path, truth)
    drive = drive_from_columns(columns, source=str(drive_path))
    params = jm.make_params(truth["params"])
    inputs = jax.tree_util.tree_map(jnp.asarray, drive.inputs)
    t = np.asarray(drive.inputs.time_s)
    ref = np.asarray(truth["heading_rad"])
    errors, rmse = {}, {}
    for mode in MODES_SHOWN:
        out = jm.run(params, inputs, jm.Config(mode=mode))
        errors[mode] = np.rad2deg(np.angle(np.exp(1j * (np.asarray(out.heading) - ref))))
        rmse[mode] = heading_rmse_deg(out.heading, ref, t)
    _say(f"\n1. Heading on a {duration_s / 60:.0f}-minute simulated mixed drive with magnetic anomalies "
         f"(true parameters, RMSE after the first minute)")
    _say("   " + "  ".join(f"{m:>13s}" for m in MODES_SHOWN))
    _say("   " + "  ".join(f"{rmse[m]:12.2f}°" for m in MODES_SHOWN))

    from .plots import pyplot, save_figure

    plt = pyplot()

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for mode in ("compass", "odometer", "complementary", "kalman"):
        ax.plot(t / 60.0, errors[mode], lw=0.8 if mode == "compass" else 1.2,
                label=f"{mode} (RMSE {rmse[mode]:.2f}°)", alpha=0.6 if mode == "compass" else 1.0)
    ax.set_xlabel("time (min)")
    ax.set_ylabel("heading error (deg)")
    ax.set_title("odocompass: heading error against time, simulated mixed drive")
    ax.set_ylim(-15, 15)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, out_dir / "heading_error.png", dpi=120)
    _say(f"   plot: {out_dir / 'heading_error.png'}")
    return rmse


def identify_vehicle(out_dir: Path, minutes: float):
    import jaxmodel as jm

    from .drive_log import drive_from_columns
    from .identify import identify
    from .simulate import simulate

    nominal = jm.params_to_dict(jm.make_params())
    true = dict(nominal, P=nominal["P"] * 1.3, B=nominal["B"] * 1.03, T_F=nominal["T_F"] * 1.03,
                a=nominal["a"] * 1.6)
    plan = [("mixed", 11, "train"), ("parking", 12, "train"), ("urban", 13, "validate")]
    drives = {}
    for scenario, seed, role in plan:
        duration = minutes * 60.0 * (0.5 if scenario == "parking" else 1.0)
        columns, _ = simulate(scenario, duration, seed=seed, params=true)
        drives[(scenario, role)] = drive_from_columns(columns, source=f"simulated {scenario} (seed {seed})")
    train = [d for (s, r), d in drives.items() if r == "train"]
    validate = [d for (s, r), d in drives.items() if r == "validate"]
    _say(f"\n2. Identification: a vehicle whose P, B, T_F, a differ from the starting file; "
         f"{len(train)} training drives, {len(validate)} validation drive")
    t0 = time.perf_counter()
    from .console import progress_enabled

    fitted, report = identify(train, jm.make_params(nominal), fit=("P", "B", "T_F", "a"), validate_drives=validate,
                              mode="odometer", progress=progress_enabled(), plots_dir=out_dir / "identification")
    wall = time.perf_counter() - t0
    fitted_d = jm.params_to_dict(fitted)
    _say(f"   {'parameter':10s} {'start':>12s} {'fitted':>12s} {'true':>12s}")
    for k in ("P", "B", "T_F", "a"):
        _say(f"   {k:10s} {nominal[k]:12.6g} {fitted_d[k]:12.6g} {true[k]:12.6g}")
    _say("   odometer-only heading error against the reference, RMSE in deg (absolute: as in the plot legend; "
         "offset removed: each drive's constant start error taken out)")
    _say(f"   {'drive':38s} {'before':>9s} {'after':>9s}   {'offset removed: before':>22s} {'after':>9s}")
    for row in report.get("drives", []):
        _say(f"   {row['role'] + ': ' + row['name']:38s} {row['odometer_rmse_before_deg']:9.2f} "
             f"{row['odometer_rmse_after_deg']:9.2f}   {row['odometer_rmse_offset_removed_before_deg']:22.2f} "
             f"{row['odometer_rmse_offset_removed_after_deg']:9.2f}")
    for w in report.get("warnings", []):
        _say(f"   warning: {w}")
    _say(f"   identify took {wall:.1f} s; report and plots in {out_dir / 'identification'}")
    jm.save_params(out_dir / "identified.json", fitted, report)
    return out_dir / "identified.json", true


def cosimulate(out_dir: Path, params_path: Path, true_params: dict, stop_time: float):
    from fmu.build import build_estimator
    from fmu.cosim import demo_cosimulation

    fmu_dir = out_dir / "fmu"  # under --out-dir, like everything the demo writes
    fmu_path = build_estimator(fmu_dir / "OdoCompass.fmu", params_path)
    _say(f"\n3. FMU: built {fmu_path} with the identified parameters; co-simulating it with a vehicle FMU "
         f"of the same (true) vehicle in fmpy ({stop_time:.0f} s) and through an SSP file")
    summary = demo_cosimulation(out_dir / "cosim", estimator_fmu=fmu_path, stop_time=stop_time,
                                fmu_dir=fmu_dir, true_params=true_params)
    _say(f"   fmpy master: ended at {summary['end_time']:.1f} s, heading RMSE {summary['rmse_deg']:.2f}° "
         f"against the vehicle's true heading")
    if "ssp_path" in summary:
        _say(f"   SSP ({Path(summary['ssp_path']).name}): ended at {summary['ssp_end_time']:.1f} s, "
             f"heading RMSE {summary['ssp_rmse_deg']:.2f}°")
    _say(f"   plot: {summary['plot']}")
    return {k: v for k, v in summary.items() if k not in ("time", "true_heading", "heading", "series")}


def main(args) -> int:
    from .outputs import check_output_dir, write_text

    out_dir = check_output_dir(args.out_dir, label="--out-dir")  # before any work
    out_dir.mkdir(parents=True, exist_ok=True)
    quick = bool(getattr(args, "quick", False))
    t0 = time.perf_counter()
    rmse = estimate_modes(out_dir, duration_s=300.0 if quick else 900.0)
    params_path, true_params = identify_vehicle(out_dir, minutes=4.0 if quick else 12.0)
    cosim = cosimulate(out_dir, params_path, true_params, stop_time=120.0 if quick else 300.0)
    summary = dict(heading_rmse_deg=rmse, identified_params=str(params_path),
                   cosimulation=cosim)
    write_text(out_dir / "summary.json", json.dumps(summary, indent=2, default=str) + "\n")
    _say(f"\ndemo finished in {time.perf_counter() - t0:.0f} s; outputs in {out_dir}/")
    return 0


if __name__ == "__main__":
    sys.exit(main(None))
