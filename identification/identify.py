"""Parameter identification on logged drives: ``identify(...)`` (the command is identify_command.py).

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
  Compass keys (``compass_fit.COMPASS_KEYS``: X0, Y0, rotation, variation, the deviation curve)
  go to a stage "compass" in between, on the compass heading (US 4,734,863 FIG. 8A).
* mode ``complementary`` / ``kalman``: one stage, every key on that mode's absolute heading.

Reference (issue 14): ``reference="heading"`` fits against ``ref_heading_deg`` (loss.py);
``"fixes"`` against the position fixes, the course of chords of the dead-reckoned track
(fixes_loss.py); ``"auto"`` takes the heading when every training drive has one.

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

from . import fixes_loss as FX
from . import loss as L
from . import report as R
from .compass_fit import COMPASS_KEYS, deviation_harmonics
from .errors import OdoCompassError
from .identify_eval import Evaluator, drive_name, rmse_rows, stack

MODES = ("odometer", "complementary", "kalman")
REFERENCES = ("heading", "fixes", "auto")
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


START_RATIO_TOLERANCE = 2e-3
"""A fitted dpp starts from the training drives' own tyre ratio where the file's is further than this from it
(``_start_tyres``; 2e-3 turns the wheel heading by ~30 deg over a 30-s increment at 15 m/s: no wrap)."""


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


_drive_name = drive_name


def _has_ref(d) -> bool:
    return d.ref_heading is not None and bool(np.any(np.isfinite(d.ref_heading)))


def _ref_heading_column(d) -> str:
    """How the drive's reference heading column stands, for an error that says which."""
    if d.ref_heading is None:
        return "column 'ref_heading_deg'"
    return "column 'ref_heading_deg' is there, but every value is empty or NaN"


def resolve_reference(reference: str, train, validate) -> str:
    """'heading' or 'fixes' from ``reference`` ('auto': the reference heading when every training
    drive has one, else the fixes); a drive lacking what the choice needs is refused by name."""
    if reference not in REFERENCES:
        raise OdoCompassError(f"--reference: unknown reference {reference!r}; expected one of {', '.join(REFERENCES)}")
    if reference == "auto":
        reference = "heading" if all(_has_ref(d) for d in train) else "fixes"
        for d in train + validate:
            if not _has_ref(d) and not FX.has_fixes(d):
                raise OdoCompassError(f"{_drive_name(d)}: neither a reference heading ({_ref_heading_column(d)}) "
                                      f"nor position fixes (columns 'fix_east_m', 'fix_north_m', 'fix_valid'): "
                                      f"identification needs one of them")
    for d in train + validate:
        if reference == "heading" and not _has_ref(d):
            raise OdoCompassError(f"{_drive_name(d)}: no reference heading ({_ref_heading_column(d)}), which "
                                  f"--reference heading needs (use --reference fixes with position fixes)")
        if reference == "fixes" and not FX.has_fixes(d):
            n = int(np.count_nonzero(np.asarray(d.inputs.fix_valid) > 0.5))
            raise OdoCompassError(f"{_drive_name(d)}: {n} valid position fix{'es' if n != 1 else ''} (columns "
                                  f"'fix_east_m', 'fix_north_m', 'fix_valid'); --reference fixes needs at least 2"
                                  + ("" if _has_ref(d) else " (and the log has no 'ref_heading_deg' either)"))
    return reference


def plan_stages(keys: Sequence[str], mode: str, increment_s: float, increment_m: float = 0.0) -> list[Stage]:
    """Stages of mode ``odometer``: wheel keys on the odometer heading, compass keys (compass_fit)
    on the compass heading, the other filter keys on the complementary heading; other modes: one."""
    if mode == "odometer":
        wheel = tuple(k for k in keys if k not in L.FILTER_KEYS)
        comp = tuple(k for k in keys if k in COMPASS_KEYS)
        filt = tuple(k for k in keys if k in L.FILTER_KEYS and k not in COMPASS_KEYS)
        stages = []
        if wheel:
            stages.append(Stage("wheel", wheel, "wheel_heading", "odometer", increment_s,
                                align=increment_s <= 0 and increment_m <= 0, lag_m=increment_m))
        if comp:
            stages.append(Stage("compass", comp, "heading", "compass", 0.0))
        if filt:
            stages.append(Stage("filter", filt, "heading", "complementary", 0.0))
        return stages
    return [Stage(mode, tuple(keys), "heading", mode, 0.0)]


def _heading_problem(stage, space, base, inputs, ref, mask, cfg, start, decorrelation_s):
    """The stage problem against the reference heading (loss.py) and its loss's description."""
    import jax.numpy as jnp

    prev = sample_weight = None
    if stage.lag_m > 0:  # heading changes over a travelled distance, each sample weighted by its distance
        dist = L.travelled_distance(inputs, start)
        prev = L.increment_index(dist, stage.lag_m)
        ds = np.diff(dist, axis=-1, prepend=dist[..., :1])
        sample_weight = jnp.asarray(ds)
        n_eff = np.where(mask.sum(-1) > 0, np.maximum(np.sum(mask * ds, axis=-1) / stage.lag_m, 1.0), 0.0)
        text = f"1 - cos of the heading change error over {stage.lag_m:g} m travelled"
    elif stage.lag_s > 0:  # heading changes over a time span (per drive, robust to jitter and dropped samples)
        prev = L.increment_index(np.asarray(inputs.time_s), stage.lag_s)
        n_eff = L.effective_counts(np.asarray(inputs.time_s), mask, stage.lag_s)
        text = f"1 - cos of the heading change error over {stage.lag_s:g} s"
    else:
        n_eff = L.effective_counts(np.asarray(inputs.time_s), mask, decorrelation_s)
        text = "1 - cos of the absolute heading error" + (" (per-drive offset removed)" if stage.align else "")
    problem = L.StageProblem(space, base, inputs, jnp.asarray(ref), jnp.asarray(mask), cfg, stage.field_name,
                             stage.align, n_eff, 0, prev, sample_weight)
    return problem, text


def _fixes_problem(stage, space, base, inputs, sample_mask, cfg, settings):
    """The stage problem against the fixes (fixes_loss.py) and its loss's description."""
    absolute = stage.field_name != "wheel_heading"
    inc = settings.increment_s if stage.lag_s > 0 or stage.lag_m > 0 else 0.0  # --increment-s 0: offset profiled
    problem = FX.build_problem(space, base, inputs, sample_mask, cfg, absolute=absolute, increment_s=inc,
                               settings=settings, align=stage.align, straight=stage.name == "compass")
    what = (f"the change over {inc:g} s of" if problem.prev is not None
            else "the per-drive offset-removed" if problem.align else "the absolute")
    text = (f"1 - cos of {what} course error of {settings.window_s:g} s chords of the {stage.mode} track "
            f"against the fixes (weights 1/(2 sigma_f^2/|d|^2 + sigma_h^2))"
            + (f", chords turning less than {settings.straight_deg:g} deg" if problem.straight_deg > 0 else ""))
    return problem, text


def _fit_stage(fun, gn, space, use_forward, max_iter, gtol, ftol, tick):
    """Optimise one stage; parameters reported not identifiable are held at their start and the
    others re-optimised.  Returns (first result, final result, ratio, se, corr, signal, status, frozen)."""
    import jax.numpy as jnp

    from .optimize import minimize

    res = minimize(fun, np.zeros(space.dim), max_iter=max_iter, gtol=gtol, ftol=ftol, callback=tick)
    hess = np.asarray(res.extra[0]) if use_forward else np.asarray(gn(jnp.asarray(res.z))[2])
    _, ratio, se, corr = R.laplace(hess, space.dtheta_dz(res.z))
    signal = np.diag(hess) - 1.0 > 1e-9
    status = [R.verdict(float(r), bool(s)) for r, s in zip(ratio, signal)]
    frozen = np.array([s == "not identifiable" for s in status])
    res_final = res
    if frozen.any() and not frozen.all():
        # keep them at the start value (z = 0) and re-optimise the others around that
        z_fix = np.where(frozen, 0.0, res.z)
        res_final = minimize(fun, z_fix, max_iter=max_iter, gtol=gtol, ftol=ftol, callback=tick, frozen=frozen)
        hess = np.asarray(res_final.extra[0]) if use_forward else np.asarray(gn(jnp.asarray(res_final.z))[2])
        _, _ratio_f, se, corr = R.laplace(hess, space.dtheta_dz(res_final.z))
    elif frozen.all():
        res_final.z = np.zeros_like(res.z)
    return res, res_final, ratio, se, corr, signal, status, frozen


def _with_circle(fun, space, circle):
    """``fun`` (z -> (F, grad, [GN Hessian, ...])) plus the field circle's measurement of the hard-iron
    offset, ½ (theta - c)ᵀ Σ⁻¹ (theta - c) over (X0, Y0), exact in z (their transform is the identity:
    theta = u0 + s z).  None: ``fun`` unchanged (no circle, or X0 and Y0 not both in this stage)."""
    if circle is None or not {"X0", "Y0"} <= set(space.labels):
        return fun
    idx = np.array([space.labels.index("X0"), space.labels.index("Y0")])
    centre, cov = circle[0], circle[1]
    prec = np.linalg.inv(cov)
    sc = np.asarray(space.s, dtype=np.float64)[idx]
    u0 = np.asarray(space.u0, dtype=np.float64)[idx]
    a = sc[:, None] * prec * sc[None, :]             # Hessian in z
    dim = space.dim

    def wrapped(z):
        out = fun(z)
        zi = np.asarray(z, dtype=np.float64)[idx]
        dev = u0 + sc * zi - centre
        value = out[0] + 0.5 * float(dev @ prec @ dev)
        g_add = np.zeros(dim)
        g_add[idx] = sc * (prec @ dev)
        grad = np.asarray(out[1], dtype=np.float64) + g_add
        rest = list(out[2:])
        if rest:
            h = np.array(rest[0], dtype=np.float64)
            h[np.ix_(idx, idx)] += a
            rest[0] = h
        return (value, grad, *rest)

    return wrapped


def _check_arguments(mode, max_iter, derivatives, field_circle) -> None:
    """One-line errors for arguments ``identify`` cannot use."""
    if mode not in MODES:
        raise OdoCompassError(f"identify: unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    if not (isinstance(max_iter, int) and max_iter >= 1):
        raise OdoCompassError(f"--max-iter must be a positive integer, got {max_iter!r}")
    if derivatives not in ("auto", "forward", "reverse"):
        raise OdoCompassError(f"derivatives must be 'auto', 'forward' or 'reverse', got {derivatives!r}")
    if field_circle not in ("auto", "on", "off"):
        raise OdoCompassError(f"field_circle must be 'auto', 'on' or 'off', got {field_circle!r}")


@dataclass
class _Problem:
    """What every stage of one ``identify`` call shares: the stacked training drives, the start (prior means),
    the estimator switches and the optimiser's settings."""
    keys: tuple
    start: Any
    inputs: Any
    ref: Any
    sample_mask: Any
    mask: Any
    reference: str
    prior_std: Mapping[str, float] | None
    decorrelation_s: float
    fix_settings: Any
    circle: Any
    switches: dict          # refine_a, calibration, track of jaxmodel.Config
    derivatives: str
    max_iter: int
    gtol: float
    ftol: float
    progress: bool


def _fit_one_stage(problem: _Problem, stage: Stage, current):
    """Fit one stage from ``current``; returns (new current Params, {label: parameter row}, labels, correlation
    block, stage report, warning or None)."""
    import jax.numpy as jnp

    import jaxmodel

    t_stage = time.perf_counter()
    cfg = jaxmodel.Config(mode=stage.mode, **problem.switches)
    space = L.make_space(stage.keys, problem.start, problem.prior_std, all_keys=problem.keys)
    if problem.reference == "fixes":
        loss_problem, loss_text = _fixes_problem(stage, space, current, problem.inputs, problem.sample_mask, cfg,
                                                 problem.fix_settings)
    else:
        loss_problem, loss_text = _heading_problem(stage, space, current, problem.inputs, problem.ref, problem.mask,
                                                   cfg, problem.start, problem.decorrelation_s)
    use_forward = problem.derivatives == "forward" or (problem.derivatives == "auto" and space.dim <= FORWARD_MAX_DIM)
    gn = _with_circle(L.forward_value_grad_gn(loss_problem), space, problem.circle)
    fun = gn if use_forward else _with_circle(L.reverse_value_grad(loss_problem, checkpoint=True), space,
                                              problem.circle)
    bar = _progress(problem.progress, problem.max_iter, f"identify [{stage.name}] {','.join(stage.keys)}")

    def tick(it, value, gmax):
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"loss={value:.6g} |grad|={gmax:.2g}")

    try:
        res, res_final, ratio, se, corr, signal, status, frozen = _fit_stage(
            fun, gn, space, use_forward, problem.max_iter, problem.gtol, problem.ftol, tick)
    finally:
        if bar is not None:
            bar.total = bar.n
            bar.refresh()
            bar.close()
    z = np.asarray(res_final.z)
    # A key held at z = 0 (not identifiable) keeps its start exactly (P 0.125 once came back 0.12500000000000003).
    unmoved = {key: getattr(current, key) for key, _tr, sl in space._segments() if not np.any(z[sl])}
    current = space.to_params(jnp.asarray(z), current)._replace(**unmoved)
    iters = res.iterations + (res_final.iterations if res_final is not res else 0)
    evals = res.evaluations + (res_final.evaluations if res_final is not res else 0)
    rows = parameter_rows(space, stage.name, z, se, ratio, signal, status)
    stage_report = {
        "name": stage.name, "keys": list(stage.keys), "heading": stage.field_name,
        "estimator_mode": stage.mode, "reference": problem.reference, "loss": loss_text,
        "effective_errors_per_drive": [float(x) for x in loss_problem.n_eff],
        "derivatives": "forward" if use_forward else "reverse (checkpointed)",
        "iterations": iters, "evaluations": evals, "converged": bool(res_final.converged),
        "stop_reason": res_final.reason, "loss_history": [float(v) for v in res.history],
        "loss_history_refit": [float(v) for v in res_final.history] if res_final is not res else [],
        "refit_with_fixed": [space.labels[j] for j in np.flatnonzero(frozen)],
        "wall_time_s": time.perf_counter() - t_stage,
    }
    if problem.circle is not None and {"X0", "Y0"} <= set(space.labels):
        stage_report["loss"] += (" + the field circle's (X0, Y0) as a measurement "
                                 "(compass_fit.field_circle, report.field_circle)")
    warning = None if res_final.converged else f"stage '{stage.name}' did not converge: {res_final.reason}"
    return current, rows, list(space.labels), corr, stage_report, warning


def _optional_report_parts(problem: _Problem, fitted) -> dict[str, Any]:
    """The report's sections that only some fits have: fixes settings, the field circle, the deviation curve."""
    parts: dict[str, Any] = {}
    settings, circle = problem.fix_settings, problem.circle
    if problem.reference == "fixes":
        parts["fixes"] = {"window_s": settings.window_s, "increment_s": settings.increment_s,
                          "fix_sigma_m": settings.fix_sigma_m, "heading_floor_deg": settings.heading_floor_deg,
                          "min_dist_m": settings.min_dist_m, "straight_deg": settings.straight_deg}
    if circle is not None:
        parts["field_circle"] = {"X0": float(circle[0][0]), "Y0": float(circle[0][1]),
                                 "std_error": [float(v) for v in np.sqrt(np.diag(circle[1]))],
                                 "correlation": float(circle[1][0, 1] / math.sqrt(circle[1][0, 0] * circle[1][1, 1])),
                                 **circle[2]}
    if "deviation_deg" in problem.keys:
        parts["deviation_deg"] = {"before": [float(v) for v in np.asarray(problem.start.deviation_deg)],
                                  "after": [float(v) for v in np.asarray(fitted.deviation_deg)],
                                  "harmonics": list(deviation_harmonics(problem.keys))}
    return parts


def identify(train_drives, init_params, fit=L.DEFAULT_FIT, validate_drives=(), mode: str = "odometer",
             max_iter: int = 400, progress: bool = True, *, config=None, refine_a: bool = True,
             calibration: bool = False, track: str = "closed_form", prior_std: Mapping[str, float] | None = None,
             decorrelation_s: float = L.DEFAULT_DECORRELATION_S, increment_s: float = DEFAULT_INCREMENT_S,
             increment_m: float = 0.0, reference: str = "auto", fix_settings: FX.FixSettings | None = None,
             gtol: float = 1e-3, ftol: float = 1e-7, derivatives: str = "auto", plots_dir=None,
             field_circle: str = "auto"):
    """Identify ``fit`` from ``train_drives``; returns (fitted Params, report dict).  See the module docstring.

    ``config`` (a jaxmodel.Config) overrides refine_a/calibration/track; its mode is ignored
    (``mode`` decides).  ``derivatives``: 'forward', 'reverse' or 'auto'.  ``reference``:
    'heading' (``ref_heading_deg``), 'fixes' (position fixes, ``fixes_loss``) or 'auto'.
    """
    import jax

    import jaxmodel

    t_start = time.perf_counter()
    if not jax.config.jax_enable_x64:
        raise OdoCompassError("odocompass needs 64-bit JAX: call jax.config.update('jax_enable_x64', True)")
    _check_arguments(mode, max_iter, derivatives, field_circle)
    if config is not None:
        refine_a, calibration, track = config.refine_a, config.calibration, config.track
    switches = dict(refine_a=bool(refine_a), calibration=bool(calibration), track=str(track))
    keys = L.parse_fit(fit)
    train = [_as_drive(d) for d in train_drives]
    validate = [_as_drive(d) for d in (validate_drives or ())]
    if not train:
        raise OdoCompassError("identify needs at least one training drive")
    start = _as_params(init_params)
    jaxmodel.validate_params(start)
    requested_reference = reference
    reference = resolve_reference(reference, train, validate)

    start, tyres_note = _start_tyres(start, keys, reference, train)
    inputs, ref, sample_mask, mask = stack(train)
    warnings: list[str] = [tyres_note] if tyres_note else []
    eval_mode = "kalman" if mode == "kalman" else "complementary"
    eval_config = jaxmodel.Config(mode=eval_mode, **switches)
    all_drives = train + validate
    roles = ["train"] * len(train) + ["validate"] * len(validate)
    evaluator = Evaluator(all_drives, eval_config, fixes=any(FX.has_fixes(d) for d in all_drives))
    ev_before = evaluator(start)

    circle = _field_circle_start(keys, field_circle, reference, inputs, sample_mask, start)
    problem = _Problem(keys=keys, start=start, inputs=inputs, ref=ref, sample_mask=sample_mask, mask=mask,
                       reference=reference, prior_std=prior_std, decorrelation_s=decorrelation_s,
                       fix_settings=fix_settings or FX.FixSettings(), circle=circle,
                       switches=switches,
                       derivatives=derivatives, max_iter=max_iter, gtol=gtol, ftol=ftol, progress=progress)
    fitted, param_rows, stage_reports, corr_labels, corr_blocks = _fit_stages(
        problem, plan_stages(keys, mode, increment_s, increment_m), warnings)
    ev_after = evaluator(fitted)
    rows = rmse_rows(ev_before, ev_after, all_drives, roles, mode, evaluator)
    warnings += R.identifiability_warnings(param_rows, R.identifiability_context(ev_after, len(train)), KEY_HINTS)
    full_corr = R.block_correlation(corr_labels, corr_blocks)
    warnings += _correlation_warnings(corr_labels, full_corr)

    report: dict[str, Any] = {
        "fit": list(keys),
        "mode": mode,
        "reference": reference,
        "reference_requested": requested_reference,
        "rmse_heading": "odometer-only heading" if mode == "odometer" else f"{mode} heading",
        "config": dict(switches),
        "optimizer": "optax.scale_by_lbfgs (memory 10) + backtracking Armijo line search, whitened "
                     "unconstrained coordinates, MAP prior N(start, prior_std)",
        "convergence": {"gtol": gtol, "ftol": ftol, "max_iter": max_iter},
        "decorrelation_s": decorrelation_s,
        "increment_s": increment_s,
        "parameters": param_rows,
        "correlation": {"parameters": corr_labels,
                        "matrix": [[None if not math.isfinite(v) else round(float(v), 6) for v in r] for r in full_corr],
                        "note": "null: stages are fitted one after the other; cross-stage correlations are not estimated"},
        "effective_track": R.effective_track_table(start, fitted),
        "drives": rows,
        "stages": stage_reports,
        "iterations": sum(st["iterations"] for st in stage_reports),
        "evaluations": sum(st["evaluations"] for st in stage_reports),
        "warnings": warnings,
        **_optional_report_parts(problem, fitted),
    }
    if plots_dir is not None:
        _write_plots(report, plots_dir, (ev_before, ev_after, all_drives, roles, start, fitted, stage_reports, mode),
                     n_train=len(train))
    report["wall_time_s"] = time.perf_counter() - t_start
    return fitted, report


def _start_tyres(start, keys, reference, train):
    """(start, note or None): a fitted dpp_right (else dpp_left) started from the tyres' ratio that the training drives'
    reference heading gives (wheel_scales.ratio_from_reference) where the file's is more than START_RATIO_TOLERANCE
    from it.  The heading changes the wheel stage fits wrap at +-180 deg: a 1.25 % mismatch the file did not know
    turned the wheel heading by ~200 deg within 30 s at 15 m/s, and the fit went to +2.1 % (independent simulator,
    vehicle 5; docs/tuning.md, stop 89).  The start is also the prior's mean."""
    from . import wheel_scales

    fitted = [k for k in ("dpp_right", "dpp_left") if k in keys]
    if reference != "heading" or not fitted:
        return start, None
    ratio = wheel_scales.ratio_from_reference(start, train)
    file_ratio = float(start.dpp_right) / float(start.dpp_left)
    if ratio is None or abs(ratio / file_ratio - 1.0) <= START_RATIO_TOLERANCE:
        return start, None
    key = fitted[0]
    new = (start._replace(dpp_right=np.float64(float(start.dpp_left) * ratio)) if key == "dpp_right"
           else start._replace(dpp_left=np.float64(float(start.dpp_right) / ratio)))
    return new, (f"{key} starts at {float(getattr(new, key)):.9g} m, not the file's {float(getattr(start, key)):.9g}: "
                 f"against their reference heading the training drives' straight windows put the tyres "
                 f"{1e6 * (ratio - 1.0):+.0f} ppm apart, the file {1e6 * (file_ratio - 1.0):+.0f} ppm (the prior is "
                 f"centred there too)")


def parameter_rows(space, stage_name, z, se, ratio, signal, status) -> dict[str, dict]:
    """The report's "parameters" rows of one stage's coordinates (``identify`` and ``fleet_fit.fit_group``): start
    and fitted value at the whitened coordinates ``z``, standard error ``se``, posterior-to-prior ratio ``ratio``,
    whether the drives inform it (``signal``) and its verdict (``status``), per label of ``space``."""
    theta = space.theta(z)
    theta0 = space.theta(np.zeros_like(z))
    return {label: {
        "start": float(theta0[j]), "fitted": float(theta[j]), "std_error": float(se[j]),
        "relative_change": float(theta[j] / theta0[j] - 1.0) if theta0[j] != 0 else None,
        "prior_std_unconstrained": float(space.s[j]),
        "transform": space.transforms[list(space.keys).index(label.split("[")[0])],
        "posterior_to_prior_std": float(ratio[j]), "data_signal": bool(signal[j]),
        "status": status[j], "stage": stage_name,
    } for j, label in enumerate(space.labels)}


def _field_circle_start(keys, field_circle, reference, inputs, sample_mask, start):
    """The circle fitted to the training drives' field (``compass_fit.field_circle``) that starts X0/Y0, when both
    are fitted and ``field_circle`` asks for it ('on', or 'auto' with the fixes as the reference); else None."""
    if not ("X0" in keys and "Y0" in keys
            and (field_circle == "on" or (field_circle == "auto" and reference == "fixes"))):
        return None
    from .compass_fit import field_circle as _field_circle

    return _field_circle(inputs, sample_mask, start)


def _fit_stages(problem, stages, warnings):
    """Fit ``stages`` one after the other from ``problem.start`` (``_fit_one_stage``); each stage's warning is
    appended to ``warnings``.  Returns (fitted Params, parameter rows, stage reports, correlation labels, the
    stages' correlation blocks)."""
    current = problem.start
    param_rows: dict[str, dict] = {}
    stage_reports = []
    corr_labels: list[str] = []
    corr_blocks = []
    for stage in stages:
        current, rows, labels, corr, stage_report, warning = _fit_one_stage(problem, stage, current)
        param_rows.update(rows)
        corr_labels.extend(labels)
        corr_blocks.append(corr)
        stage_reports.append(stage_report)
        if warning:
            warnings.append(warning)
    return current, param_rows, stage_reports, corr_labels, corr_blocks


def _correlation_warnings(corr_labels, full_corr):
    """One warning per pair of fitted parameters that the drives identify only in combination."""
    return [f"{a_} and {b_} are {abs(c_):.3f} {'correlated' if c_ > 0 else 'anti-correlated'}: "
            f"the drives identify a combination of them, not each one"
            for a_, b_, c_ in R.correlated_pairs(corr_labels, np.nan_to_num(full_corr))]


def _write_plots(report, plots_dir, plot_args, n_train):
    """The report's figures (``plots.write_all(plots_dir, *plot_args)``) into ``report["plots"]``; a failed plot is
    reported (``report["plot_error"]`` and a warning), never the end of a finished fit."""
    from . import plots

    try:
        report["plots"] = [str(p) for p in plots.write_all(Path(plots_dir), *plot_args, n_train=n_train)]
    except Exception as exc:  # noqa: BLE001 - any plotting failure (disk, backend) is only reported
        text = " ".join(str(exc).split()) or type(exc).__name__
        report["plot_error"] = f"{plots_dir}: plots not written: {text}"
        report["warnings"].append(report["plot_error"])


def _progress(enabled: bool, total: int, desc: str):
    if not enabled:
        return None
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, file=sys.stderr, unit="it", dynamic_ncols=True, leave=True)
    bar.set_postfix_str("compiling")
    return bar
