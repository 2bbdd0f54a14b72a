"""``odocompass identify``: the command around ``identification.identify.identify``.

    odocompass identify DRIVE... --params INIT.json --out FIT.json [--fit ...] [--validate ...] [--plots DIR]

Checks its outputs before any work, reads the drives, warns, fits, validates the fitted
parameters and writes them with the report (docs/identification.md).
"""

from __future__ import annotations

import time
from pathlib import Path

from . import loss as L
from . import report as R
from .errors import OdoCompassError
from .identify import identify


def _reuse_warnings(drives, validate) -> list[str]:
    """A drive given twice counts twice in the fit; a validation drive that is also fitted validates nothing."""
    def same(path):
        return Path(path).resolve()

    out, seen = [], set()
    for p in drives:
        if same(p) in seen:
            out.append(f"{p}: given twice among the drives to fit; it counts twice in the loss")
        seen.add(same(p))
    out += [f"{p}: a --validate drive that is also fitted; its RMSE is no held-out figure"
            for p in validate if same(p) in seen]
    return out


def main(args) -> int:
    """``odocompass identify DRIVE... --params INIT.json --out FIT.json [--fit ...] [--validate ...] [--plots DIR]``.

    Outputs are checked before any work (never an input, a writable location); the start file's
    errors name it; the drives' warnings (diagnostics) are printed before the fit and kept in the
    report; a failed plot is reported without losing the fit."""
    import jaxmodel

    from . import console
    from .diagnostics import batch_warnings, checked_params
    from .drive_log import read_drive
    from .outputs import check_output_dir, check_output_file

    t0 = time.perf_counter()
    inputs = ([("the parameter file", args.params)] + [("the drive log", d) for d in args.drives]
              + [("the validation drive log", d) for d in (args.validate or [])])
    check_output_file(args.out, inputs=inputs, label="--out", suffixes=(".json",))  # a parameter file
    if args.plots:
        check_output_dir(args.plots, inputs=inputs, label="--plots")
    start, _extra = checked_params(args.params)
    keys = L.parse_fit(args.fit)
    try:
        L.make_space(keys, start)  # a start value the parameterisation cannot take, before reading the drives
    except OdoCompassError as exc:
        raise OdoCompassError(f"{args.params}: {exc}") from None
    train = [read_drive(p) for p in args.drives]
    validate = [read_drive(p) for p in (args.validate or [])]
    drive_warnings = _reuse_warnings(args.drives, args.validate or []) + batch_warnings(train + validate, start)
    for w in drive_warnings:
        console.warn(w)
    kwargs = {}
    for name in ("refine_a", "calibration"):
        v = getattr(args, name.replace("-", "_"), None)
        if v is not None:
            kwargs[name] = v in ("on", True)
    if getattr(args, "increment_s", None) is not None:
        kwargs["increment_s"] = float(args.increment_s)
    kwargs["reference"] = getattr(args, "reference", None) or "auto"
    fitted, report = identify(train, start, fit=keys, validate_drives=validate, mode=args.mode,
                              max_iter=args.max_iter, progress=console.progress_enabled(),
                              plots_dir=args.plots, **kwargs)
    report["wall_time_s"] = time.perf_counter() - t0
    report["start_file"] = str(args.params)
    report["warnings"] = drive_warnings + R.zero_start_warnings(report, args.params) + report["warnings"]
    try:  # e.g. refine_speed_min and refine_speed_max fitted independently and crossed
        jaxmodel.validate_params(fitted)
    except jaxmodel.ParameterError as exc:
        raise OdoCompassError(f"identify: the fitted parameters are not valid, nothing written to {args.out}: "
                              f"{exc}") from None
    jaxmodel.save_params(args.out, fitted, R.json_safe(report))
    if not console.QUIET:
        print(R.format_summary(report))
    for w in report["warnings"][len(drive_warnings):]:
        console.warn(w)
    plots = f" and plots into {args.plots}" if args.plots and "plot_error" not in report else ""
    console.info(f"wrote {args.out}{plots}")
    return 0
