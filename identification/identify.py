"""Parameter identification on logged drives: ``identify(...)`` and ``odocompass identify``.

    fitted, report = identify(train_drives, init_params, fit=("P", "B", "T_F", "a", "T_C", "D_N"),
                              validate_drives=(), mode="odometer", max_iter=400, progress=True)

Drives are ``identification.drive_log.Drive`` objects (or paths, read with ``read_drive``) with a
reference heading; ``init_params`` is a Params, a dict of JSON keys or a parameter file.  Its
values are the starting point *and* the prior means (MAP).  Returns the fitted Params (same
schema; only the fitted keys change) and a JSON-ready report (see docs/identification.md).

Stages (which heading carries which parameter's signal, see identification.loss):

* mode ``odometer`` (default): stage "wheel" fits every requested key except the heading-filter and
  compass keys (``loss.FILTER_KEYS``) on the odometer heading, as heading *changes* over
  ``increment_s`` seconds (the constant error of the compass sample that starts the odometer
  heading cancels, and slowly accumulating wheel-slip noise does not dominate the fit); then
  stage "filter" fits the requested filter keys (``D_N``, ...) on the absolute complementary
  heading with the wheel parameters fixed at their fitted values.
* mode ``complementary`` / ``kalman``: one stage, every key on that mode's absolute heading.

The estimator configuration used for fitting is ``refine_a=True`` (as ``estimate``),
``calibration=False`` (the left/right calibration adapts the wheel model itself; add ``dpp_right``
to the fit set for a known mismatch instead) and the closed-form track, all overridable.
Validation drives are only evaluated, never fitted.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from . import loss as L
from . import report as R
from .errors import OdoCompassError

MODES = ("odometer", "complementary", "kalman")
FORWARD_MAX_DIM = 24
"""Up to this many fitted coordinates, derivatives come from forward mode (one vmap of jvp,
cheaper than reverse mode here, see bench/bench_grad.py); beyond it, reverse mode with a
checkpointed step."""

DEFAULT_INCREMENT_S = 30.0

KEY_HINTS = {
    "P": "P and B act only in tight turns (eq. 14: T_E ~ T_F - (1-P) B² c² / (2 T_F)); these drives reach "
         "|dD/AD| = {cmax:.3f} (99.5th percentile while moving)",
    "B": "P and B act only in tight turns (eq. 14: T_E ~ T_F - (1-P) B² c² / (2 T_F)); these drives reach "
         "|dD/AD| = {cmax:.3f} (99.5th percentile while moving)",
    "T_C": "T_C acts only through the online refinement of a (turns over 45 deg at 15-45 mph with a consistent "
           "compass, refine_a on); a was refined {refinements} times on these drives",
    "a": "a acts through a V² at speed in turns; these drives reach {vmax:.1f} m/s (99.5th percentile)",
    "D_N": "D_N sets the complementary filter's distance constant; until a drive has covered about D_N/F metres "
           "the start-up gain (1/distance driven) governs instead; the longest training drive is {dmax:.0f} m",
}


@dataclass
class Stage:
    name: str
    keys: tuple
    field_name: str          # Outputs field fitted
    mode: str                # estimator mode of this stage
    lag_s: float             # > 0: heading changes over this many seconds; 0: absolute heading
    align: bool = False
    lag_m: float = 0.0       # > 0: heading changes over this many metres travelled (overrides lag_s)


def _as_drive(d):
    from .drive_log import Drive, read_drive

    if isinstance(d, Drive):
        return d
    if isinstance(d, (str, Path)):
        return read_drive(d)
    raise OdoCompassError(f"expected a Drive or a drive log path, got {type(d).__name__}")


def _as_params(p):
    import jaxmodel

    if isinstance(p, jaxmodel.Params):
        return p
    if isinstance(p, (str, Path)):
        return jaxmodel.load_params(p)[0]
    if p is None or isinstance(p, Mapping):
        return jaxmodel.make_params({k: v for k, v in dict(p or {}).items() if k != "report"})
    raise OdoCompassError(f"expected Params, a dict or a parameter file, got {type(p).__name__}")


def _drive_name(d) -> str:
    return str(d.metadata.get("path", "<columns>")) if getattr(d, "metadata", None) else "<columns>"


def plan_stages(keys: Sequence[str], mode: str, increment_s: float, increment_m: float = 0.0) -> list[Stage]:
    if mode == "odometer":
        wheel = tuple(k for k in keys if k not in L.FILTER_KEYS)
        filt = tuple(k for k in keys if k in L.FILTER_KEYS)
        stages = []
        if wheel:
            stages.append(Stage("wheel", wheel, "wheel_heading", "odometer", increment_s,
                                align=increment_s <= 0 and increment_m <= 0, lag_m=increment_m))
        if filt:
            stages.append(Stage("filter", filt, "heading", "complementary", 0.0))
        return stages
    return [Stage(mode, tuple(keys), "heading", mode, 0.0)]


def _stack(drives):
    import jax.numpy as jnp
    import jax

    from .drive_log import stack_drives, stack_reference

    inputs, mask = stack_drives(drives)
    ref, rmask = stack_reference(drives)
    return jax.tree_util.tree_map(jnp.asarray, inputs), np.asarray(ref), np.asarray(mask * rmask)


class _Evaluator:
    """One compiled forward pass over every drive (train + validation) for RMSEs and plots."""

    FIELDS = ("heading", "wheel_heading", "curvature", "effective_track", "speed", "a", "distance")

    def __init__(self, drives, config):
        import jax

        self.inputs, self.ref, self.mask = _stack(drives)
        self.config = config
        self._fn = jax.jit(lambda p: L.batch_outputs(p, self.inputs, self.config, self.FIELDS))

    def __call__(self, params) -> dict[str, np.ndarray]:
        import jax

        out = jax.device_get(self._fn(params))
        d = {k: np.asarray(v) for k, v in zip(self.FIELDS, out)}
        d["weight"] = self.mask * (np.asarray(out[-1]) > 0.5)
        d["ref"] = self.ref
        d["time_s"] = np.asarray(self.inputs.time_s)
        return d


def _rmse_rows(ev_before, ev_after, drives, roles, mode) -> list[dict]:
    rows = []
    primary = "wheel_heading" if mode == "odometer" else "heading"
    for b, (d, role) in enumerate(zip(drives, roles)):
        n = len(np.asarray(d.inputs.time_s))
        row: dict[str, Any] = {"role": role, "name": _drive_name(d), "n_samples": n,
                               "duration_s": float(np.asarray(d.inputs.time_s)[-1] - np.asarray(d.inputs.time_s)[0])}
        for tag, ev in (("before", ev_before), ("after", ev_after)):
            w = ev["weight"][b]
            e_odo = ev["wheel_heading"][b] - ev["ref"][b]
            e_est = ev["heading"][b] - ev["ref"][b]
            row[f"odometer_rmse_{tag}_deg"] = R.rmse_deg(e_odo, w)
            row[f"odometer_rmse_offset_removed_{tag}_deg"] = R.rmse_deg(e_odo, w, align=True)
            est_name = "kalman" if mode == "kalman" else "complementary"
            row[f"{est_name}_rmse_{tag}_deg"] = R.rmse_deg(e_est, w)
            row[f"rmse_{tag}_deg"] = R.rmse_deg(ev[primary][b] - ev["ref"][b], w)
        rows.append(row)
    return rows


def identify(train_drives, init_params, fit=L.DEFAULT_FIT, validate_drives=(), mode: str = "odometer",
             max_iter: int = 400, progress: bool = True, *, config=None, refine_a: bool = True,
             calibration: bool = False, track: str = "closed_form", prior_std: Mapping[str, float] | None = None,
             decorrelation_s: float = L.DEFAULT_DECORRELATION_S, increment_s: float = DEFAULT_INCREMENT_S,
             increment_m: float = 0.0,
             gtol: float = 1e-3, ftol: float = 1e-7, derivatives: str = "auto", plots_dir=None):
    """Identify ``fit`` from ``train_drives``; returns (fitted Params, report dict).  See the module docstring.

    ``config`` (a jaxmodel.Config) overrides refine_a/calibration/track; its mode is ignored
    (``mode`` decides).  ``derivatives``: 'forward', 'reverse' or 'auto'.
    """
    import jax
    import jax.numpy as jnp

    import jaxmodel
    from jaxmodel.track import effective_track

    t_start = time.perf_counter()
    if not jax.config.jax_enable_x64:
        raise OdoCompassError("odocompass needs 64-bit JAX: call jax.config.update('jax_enable_x64', True)")
    if mode not in MODES:
        raise OdoCompassError(f"identify: unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    if not (isinstance(max_iter, int) and max_iter >= 1):
        raise OdoCompassError(f"--max-iter must be a positive integer, got {max_iter!r}")
    if derivatives not in ("auto", "forward", "reverse"):
        raise OdoCompassError(f"derivatives must be 'auto', 'forward' or 'reverse', got {derivatives!r}")
    if config is not None:
        refine_a, calibration, track = bool(config.refine_a), bool(config.calibration), str(config.track)
    keys = L.parse_fit(fit)
    train = [_as_drive(d) for d in train_drives]
    validate = [_as_drive(d) for d in (validate_drives or ())]
    if not train:
        raise OdoCompassError("identify needs at least one training drive")
    start = _as_params(init_params)
    jaxmodel.validate_params(start)
    for d in train + validate:
        if d.ref_heading is None or not np.any(np.isfinite(d.ref_heading)):
            raise OdoCompassError(f"{_drive_name(d)}: no reference heading (column 'ref_heading_deg'), "
                                  f"which identification needs")

    inputs, ref, mask = _stack(train)
    stages = plan_stages(keys, mode, increment_s, increment_m)
    warnings: list[str] = []
    eval_mode = "kalman" if mode == "kalman" else "complementary"
    eval_config = jaxmodel.Config(mode=eval_mode, refine_a=refine_a, calibration=calibration, track=track)
    all_drives = train + validate
    roles = ["train"] * len(train) + ["validate"] * len(validate)
    evaluator = _Evaluator(all_drives, eval_config)
    ev_before = evaluator(start)

    current = start
    param_rows: dict[str, dict] = {}
    stage_reports = []
    corr_labels: list[str] = []
    corr_blocks = []
    total_iter = total_eval = 0
    for si, stage in enumerate(stages):
        t_stage = time.perf_counter()
        cfg = jaxmodel.Config(mode=stage.mode, refine_a=refine_a, calibration=calibration, track=track)
        space = L.make_space(stage.keys, start, prior_std)
        prev = sample_weight = None
        if stage.lag_m > 0:  # heading changes over a travelled distance, each sample weighted by its distance
            lag = 0
            dist = L.travelled_distance(inputs, start)
            prev = L.increment_index(dist, stage.lag_m)
            ds = np.diff(dist, axis=-1, prepend=dist[..., :1])
            sample_weight = jnp.asarray(ds)
            n_eff = np.where(mask.sum(-1) > 0, np.maximum(np.sum(mask * ds, axis=-1) / stage.lag_m, 1.0), 0.0)
        elif stage.lag_s > 0:  # heading changes over a time span (per drive, robust to jitter and dropped samples)
            lag = 0
            prev = L.increment_index(np.asarray(inputs.time_s), stage.lag_s)
            n_eff = L.effective_counts(np.asarray(inputs.time_s), mask, stage.lag_s)
        else:
            lag = 0
            n_eff = L.effective_counts(np.asarray(inputs.time_s), mask, decorrelation_s)
        problem = L.StageProblem(space, current, inputs, jnp.asarray(ref), jnp.asarray(mask), cfg,
                                 stage.field_name, stage.align, n_eff, lag, prev, sample_weight)
        use_forward = derivatives == "forward" or (derivatives == "auto" and space.dim <= FORWARD_MAX_DIM)
        gn = L.forward_value_grad_gn(problem)
        if use_forward:
            fun = gn
        else:
            vg = L.reverse_value_grad(problem, checkpoint=True)
            fun = vg

        bar = _progress(progress, max_iter, f"identify [{stage.name}] {','.join(stage.keys)}")

        def tick(it, value, gmax, bar=bar):
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(f"loss={value:.6g} |grad|={gmax:.2g}")

        from .optimize import minimize

        z0 = np.zeros(space.dim)
        try:
            res = minimize(fun, z0, max_iter=max_iter, gtol=gtol, ftol=ftol, callback=tick)
            hess = np.asarray(res.extra[0]) if use_forward else np.asarray(gn(jnp.asarray(res.z))[2])
            _, ratio, se, corr = R.laplace(hess, space.dtheta_dz(res.z))
            signal = np.diag(hess) - 1.0 > 1e-9
            status = [R.verdict(float(r), bool(s)) for r, s in zip(ratio, signal)]
            frozen = np.array([s == "not identifiable" for s in status])
            res_final = res
            if frozen.any() and not frozen.all():
                # keep them at the start value (z = 0) and re-optimise the others around that
                z_fix = np.where(frozen, 0.0, res.z)
                res_final = minimize(fun, z_fix, max_iter=max_iter, gtol=gtol, ftol=ftol, callback=tick,
                                     frozen=frozen)
                hess = np.asarray(res_final.extra[0]) if use_forward else np.asarray(gn(jnp.asarray(res_final.z))[2])
                _, ratio_f, se, corr = R.laplace(hess, space.dtheta_dz(res_final.z))
            elif frozen.all():
                res_final = res
                res_final.z = np.zeros_like(res.z)
        finally:
            if bar is not None:
                bar.total = bar.n
                bar.refresh()
                bar.close()
        z = np.asarray(res_final.z)
        current = space.to_params(jnp.asarray(z), current)
        theta = space.theta(z)
        theta0 = space.theta(np.zeros_like(z))
        iters = res.iterations + (res_final.iterations if res_final is not res else 0)
        evals = res.evaluations + (res_final.evaluations if res_final is not res else 0)
        total_iter += iters
        total_eval += evals
        for j, label in enumerate(space.labels):
            param_rows[label] = {
                "start": float(theta0[j]), "fitted": float(theta[j]), "std_error": float(se[j]),
                "relative_change": float(theta[j] / theta0[j] - 1.0) if theta0[j] != 0 else None,
                "prior_std_unconstrained": float(space.s[j]),
                "transform": space.transforms[[k for k in space.keys].index(label.split("[")[0])],
                "posterior_to_prior_std": float(ratio[j]), "data_signal": bool(signal[j]),
                "status": status[j], "stage": stage.name,
            }
        corr_labels.extend(space.labels)
        corr_blocks.append(corr)
        stage_reports.append({
            "name": stage.name, "keys": list(stage.keys), "heading": stage.field_name,
            "estimator_mode": stage.mode,
            "loss": (f"1 - cos of the heading change error over {stage.lag_m:g} m travelled" if stage.lag_m > 0
                     else f"1 - cos of the heading change error over {stage.lag_s:g} s" if stage.lag_s > 0
                     else "1 - cos of the absolute heading error" + (" (per-drive offset removed)" if stage.align else "")),
            "effective_errors_per_drive": [float(x) for x in problem.n_eff],
            "derivatives": "forward" if use_forward else "reverse (checkpointed)",
            "iterations": iters, "evaluations": evals, "converged": bool(res_final.converged),
            "stop_reason": res_final.reason, "loss_history": [float(v) for v in res.history],
            "loss_history_refit": [float(v) for v in res_final.history] if res_final is not res else [],
            "refit_with_fixed": [space.labels[j] for j in np.flatnonzero(frozen)],
            "wall_time_s": time.perf_counter() - t_stage,
        })
        if not res_final.converged:
            warnings.append(f"stage '{stage.name}' did not converge: {res_final.reason}")

    fitted = current
    ev_after = evaluator(fitted)
    rows = _rmse_rows(ev_before, ev_after, all_drives, roles, mode)

    # context for the identifiability warnings
    w_train = ev_after["weight"][: len(train)] > 0
    moving = w_train & (ev_after["speed"][: len(train)] > 0.5)
    curv = np.abs(ev_after["curvature"][: len(train)][moving])
    cmax = float(np.percentile(curv, 99.5)) if curv.size else 0.0  # robust: isolated windows at a standstill
    speed = ev_after["speed"][: len(train)][moving]
    vmax = float(np.percentile(speed, 99.5)) if speed.size else 0.0
    a_tr = ev_after["a"][: len(train)]
    refinements = int(np.sum(np.abs(np.diff(a_tr, axis=-1)) > 0))
    dmax = float(np.max(ev_after["distance"][: len(train)], initial=0.0))
    vector_done = set()
    for label, row in param_rows.items():
        if row["status"] != "not identifiable":
            continue
        key = label.split("[")[0]
        if "[" in label:  # one line per vector key (the deviation table)
            if key in vector_done:
                continue
            vector_done.add(key)
            entries = [lb for lb, r in param_rows.items() if lb.split("[")[0] == key]
            bad = [lb for lb in entries if param_rows[lb]["status"] == "not identifiable"]
            idx = ", ".join(lb[len(key) + 1:-1] for lb in bad)
            warnings.append(f"{key}: {len(bad)} of {len(entries)} entries are not identifiable from these drives "
                            f"(posterior std >= {R.NOT_IDENTIFIABLE_RATIO} x prior std): [{idx}]; kept at their "
                            f"starting values")
            continue
        why = "the loss does not depend on it with these drives and settings" if not row["data_signal"] else \
            f"posterior std = {row['posterior_to_prior_std']:.2f} x prior std"
        hint = KEY_HINTS.get(key, "").format(cmax=cmax, vmax=vmax, refinements=refinements, dmax=dmax)
        warnings.append(f"{label} is not identifiable from these drives ({why}); kept at the starting value "
                        f"{row['start']:.6g}" + (f". {hint}" if hint else ""))
    full_corr = np.full((len(corr_labels), len(corr_labels)), np.nan)
    i0 = 0
    for block in corr_blocks:
        n = block.shape[0]
        full_corr[i0:i0 + n, i0:i0 + n] = block
        i0 += n
    for a_, b_, c_ in R.correlated_pairs(corr_labels, np.nan_to_num(full_corr)):
        warnings.append(f"{a_} and {b_} are {abs(c_):.3f} {'correlated' if c_ > 0 else 'anti-correlated'}: "
                        f"the drives identify a combination of them, not each one")

    c_grid = [0.0, 0.05, 0.1, 0.15, 0.2]

    def te(p):
        if float(p.sensor_axle) < 0.5:
            return [float(p.T_R)] * len(c_grid)
        return [float(v) for v in np.asarray(effective_track(np.asarray(c_grid), p.P, p.B, p.T_F, p.curvature_clip))]

    report: dict[str, Any] = {
        "fit": list(keys),
        "mode": mode,
        "rmse_heading": "odometer-only heading" if mode == "odometer" else f"{mode} heading",
        "config": {"refine_a": bool(refine_a), "calibration": bool(calibration), "track": track},
        "optimizer": "optax.scale_by_lbfgs (memory 10) + backtracking Armijo line search, whitened "
                     "unconstrained coordinates, MAP prior N(start, prior_std)",
        "convergence": {"gtol": gtol, "ftol": ftol, "max_iter": max_iter},
        "decorrelation_s": decorrelation_s,
        "increment_s": increment_s,
        "parameters": param_rows,
        "correlation": {"parameters": corr_labels,
                        "matrix": [[None if not math.isfinite(v) else round(float(v), 6) for v in r] for r in full_corr],
                        "note": "null: stages are fitted one after the other; cross-stage correlations are not estimated"},
        "effective_track": {"curvature": c_grid, "before_m": te(start), "after_m": te(fitted)},
        "drives": rows,
        "stages": stage_reports,
        "iterations": total_iter,
        "evaluations": total_eval,
        "warnings": warnings,
    }
    if plots_dir is not None:  # a failed plot is reported, never the end of a finished fit
        from . import plots

        try:
            report["plots"] = [str(p) for p in plots.write_all(Path(plots_dir), ev_before, ev_after, all_drives,
                                                              roles, start, fitted, stage_reports, mode,
                                                              n_train=len(train))]
        except Exception as exc:  # noqa: BLE001 - any plotting failure (disk, backend) is only reported
            text = " ".join(str(exc).split()) or type(exc).__name__
            report["plot_error"] = f"{plots_dir}: plots not written: {text}"
            warnings.append(report["plot_error"])
    report["wall_time_s"] = time.perf_counter() - t_start
    return fitted, report


def _progress(enabled: bool, total: int, desc: str):
    if not enabled:
        return None
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, file=sys.stderr, unit="it", dynamic_ncols=True, leave=True)
    bar.set_postfix_str("compiling")
    return bar


def _json_safe(value):
    """The report with NaN/inf (a drive without compass or reference has no RMSE) as null: strict JSON."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)) and not math.isfinite(float(value)):
        return None
    return value


def _zero_start_warnings(report, params_file) -> list[str]:
    out = []
    for label, row in report.get("parameters", {}).items():
        if row.get("transform") == "softplus":
            out.append(f"{label} starts at 0 in {params_file}, the boundary of a non-negative parameter: fitted as "
                       f"c softplus(u) from {row['start']:.4g} (identification.loss); fitted {row['fitted']:.6g}")
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
    check_output_file(args.out, inputs=inputs, label="--out")
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
    drive_warnings = batch_warnings(train + validate, start)
    for w in drive_warnings:
        console.warn(w)
    kwargs = {}
    for name in ("refine_a", "calibration"):
        v = getattr(args, name.replace("-", "_"), None)
        if v is not None:
            kwargs[name] = v in ("on", True)
    if getattr(args, "increment_s", None) is not None:
        kwargs["increment_s"] = float(args.increment_s)
    fitted, report = identify(train, start, fit=keys, validate_drives=validate, mode=args.mode,
                              max_iter=args.max_iter, progress=console.progress_enabled(),
                              plots_dir=args.plots, **kwargs)
    report["wall_time_s"] = time.perf_counter() - t0
    report["start_file"] = str(args.params)
    report["warnings"] = drive_warnings + _zero_start_warnings(report, args.params) + report["warnings"]
    try:  # e.g. refine_speed_min and refine_speed_max fitted independently and crossed
        jaxmodel.validate_params(fitted)
    except jaxmodel.ParameterError as exc:
        raise OdoCompassError(f"identify: the fitted parameters are not valid, nothing written to {args.out}: {exc}") from None
    jaxmodel.save_params(args.out, fitted, _json_safe(report))
    if not console.QUIET:
        print(R.format_summary(report))
    for w in report["warnings"][len(drive_warnings):]:
        console.warn(w)
    plots = f" and plots into {args.plots}" if args.plots and "plot_error" not in report else ""
    console.info(f"wrote {args.out}{plots}")
    return 0
