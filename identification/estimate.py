"""``odocompass estimate DRIVE --params P.json --out EST.csv`` (SPEC §5), and ``estimate_drive``.

``estimate_drive(params, drive, config)`` runs ``jaxmodel.run`` on a checked drive and returns
the per-sample output table as numpy columns (headings in degrees wrapped to (-180, 180]);
the demo, the identification report and the CLI share it.  The CLI writes that table
atomically (CSV, or Parquet/MDF4 when --out ends in .parquet/.mf4) and prints one summary line
on stderr: how many compass samples (NaN/inf or no field) and odometer samples (implausible
or non-finite counts; the first sample, which only sets the counter references, is not
counted) the estimator skipped.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from .drive_log import Drive, _format_of, bucket_length, pad_inputs, read_drive, wrap_deg, write_drive
from .errors import OdoCompassError

OUTPUT_COLUMNS = ("time_s", "heading_deg", "wheel_heading_deg", "compass_heading_deg", "x_m", "y_m", "speed_mps",
                  "a", "heading_reliability", "compass_valid", "odometer_valid", "dpp_ratio", "curvature",
                  "effective_track_m", "map_used")
FLAG_OUTPUTS = ("compass_valid", "odometer_valid", "map_used")


class EstimatorBug(RuntimeError):
    """The estimator produced a non-finite output: a defect in jaxmodel, not in the user's input."""


def run_padded(params, drive: Drive, config):
    """``jaxmodel.run`` on one drive, its inputs padded to ``drive_log.bucket_length`` and the outputs cut back to
    the drive's n samples: an ``Outputs`` of (n,) arrays, equal to the unpadded run (the scan is causal).  Logs of
    nearby lengths so share one compiled program (compiling is most of a short estimate; compile_cache)."""
    import jax
    import jax.numpy as jnp

    import jaxmodel

    n = len(drive.inputs.time_s)
    inputs = jax.tree_util.tree_map(jnp.asarray, pad_inputs(drive.inputs, bucket_length(n)))
    return jax.tree_util.tree_map(lambda v: v[:n], jaxmodel.run(params, inputs, config))


def estimate_drive(params, drive: Drive, config=None) -> dict[str, np.ndarray]:
    """Run the estimator over one drive; returns {column: numpy array} in OUTPUT_COLUMNS order.

    Headings are degrees wrapped to (-180, 180]; flags are int8 0/1.  Raises EstimatorBug if
    any output is NaN or infinite (the model must skip bad samples, never propagate them).
    """
    import jax

    import jaxmodel

    if not jax.config.jax_enable_x64:
        raise OdoCompassError("odocompass needs 64-bit JAX: call jax.config.update('jax_enable_x64', True)")
    config = jaxmodel.DEFAULT_CONFIG if config is None else config
    out = jax.device_get(run_padded(params, drive, config))

    def deg(v):
        return wrap_deg(np.rad2deg(np.asarray(v, dtype=np.float64)))

    def f64(v):
        return np.asarray(v, dtype=np.float64)

    cols = {
        "time_s": np.asarray(drive.inputs.time_s, dtype=np.float64),
        "heading_deg": deg(out.heading),
        "wheel_heading_deg": deg(out.wheel_heading),
        "compass_heading_deg": deg(out.compass_heading),
        "x_m": f64(out.x),
        "y_m": f64(out.y),
        "speed_mps": f64(out.speed),
        "a": f64(out.a),
        "heading_reliability": f64(out.heading_reliability),
        "compass_valid": f64(out.compass_valid),
        "odometer_valid": f64(out.odometer_valid),
        "dpp_ratio": f64(out.dpp_ratio),
        "curvature": f64(out.curvature),
        "effective_track_m": f64(out.effective_track),
        "map_used": f64(out.map_used),
    }
    bad = [k for k, v in cols.items() if not np.all(np.isfinite(v))]
    if bad:
        first = min(int(np.flatnonzero(~np.isfinite(cols[k]))[0]) for k in bad)
        raise EstimatorBug(
            f"{drive.path}: the estimator produced non-finite values in {', '.join(bad)} from row {first + 1} "
            f"(time_s={cols['time_s'][first]:.10g}, mode={config.mode}); this is a defect in jaxmodel, "
            f"please report it with the drive log")
    for k in FLAG_OUTPUTS:
        cols[k] = (cols[k] > 0.5).astype(np.int8)
    return cols


def skipped_counts(columns: dict[str, np.ndarray]) -> tuple[int, int]:
    """(compass samples skipped, odometer samples skipped) in an ``estimate_drive`` table.

    The first sample has no pulse increment (it sets the counter references) and is not counted.
    """
    compass = int(np.count_nonzero(np.asarray(columns["compass_valid"]) == 0))
    odometer = int(np.count_nonzero(np.asarray(columns["odometer_valid"])[1:] == 0))
    return compass, odometer


def main(args) -> int:
    """``odocompass estimate``: every check (output location, inputs, parameters) before the work;
    the table is written atomically; warnings (diagnostics.drive_warnings) on stderr."""
    import jaxmodel

    from . import console, wheel_scales
    from .diagnostics import drive_warnings, estimation_params
    from .outputs import atomic, check_output_file

    out_path = Path(args.out)
    drive_path = Path(args.drive)
    _format_of(out_path)  # refuse an unknown output extension before the work
    check_output_file(out_path, inputs=(("the drive log", drive_path), ("the parameter file", args.params)))
    params, extra, nominal_vehicle = estimation_params(args.params)
    drive = read_drive(drive_path)
    config = jaxmodel.Config(mode=args.mode, refine_a=args.refine_a == "on", calibration=args.calibration == "on",
                             track=args.track, robust=getattr(args, "filter", "robust") == "robust",
                             hard_iron=getattr(args, "hard_iron", "off") == "on")
    fit_dpp = wheel_scales.dpp_unknown(extra["keys"])
    params, scales = wheel_scales.for_drive(params, fit_dpp, drive, config)
    console.status(f"estimating {drive.n_samples} samples ({drive.metadata.get('duration_s', 0.0):.0f} s) "
                 f"of {drive_path} in mode {args.mode}")
    try:
        cols = estimate_drive(params, drive, config)
    except EstimatorBug as exc:
        print(f"odocompass: internal error: {exc}", file=sys.stderr)
        return 1
    with atomic(out_path) as tmp:
        write_drive(tmp, cols)
    if nominal_vehicle:
        sigma0 = jaxmodel.UNIDENTIFIED_VEHICLE["filter_scale_sigma0"]
        console.info(f"the wheel turn's scale is not given (a dpp_left or dpp_right and the sensor axle's T_F or "
                     f"T_R) in {args.params or 'the built-in defaults'}: its error learned online (filter_scale_sigma0 "
                     f"{sigma0:g}); odocompass identify finds the vehicle's own")
    elif float(params.filter_scale_speed_ref) > 0.0 and "filter_scale_speed_ref" not in extra["keys"]:
        console.info(f"the velocity coefficient a of eq. (8) is not given in {args.params}: the wheel turn's error "
                     f"at speed learned online (filter_scale_speed_ref {float(params.filter_scale_speed_ref):g} m/s); "
                     f"odocompass identify finds the vehicle's own")
    if fit_dpp and args.mode != "compass":
        console.info(wheel_scales.describe(scales, params))
    for w in drive_warnings(drive, params, cols, mode=args.mode):
        console.warn(w)
    n_compass, n_odometer = skipped_counts(cols)
    console.info(f"skipped {n_compass} compass samples, {n_odometer} odometer samples "
                 f"(of {drive.n_samples}); wrote {out_path}")
    return 0
