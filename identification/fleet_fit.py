"""Identification of a group of vehicles in one compiled program: ``identify`` vmapped over vehicles.

``fit_group(vehicles, start, keys, options)`` fits every vehicle of the group *as* ``identify``
would fit it alone (same stages, loss, MAP prior, L-BFGS rules, Laplace standard errors, frozen
refit of non-identifiable keys, report), but with one program for the whole group:

* the training drives are stacked (V vehicles, D drives, N samples): shorter drives are padded
  (``drive_log.stack_drives`` rules, mask 0), N is rounded up to a length bucket
  (``bucket_length``: at most 12.5 % padding, few distinct shapes, so a worker compiles once
  for many groups), and a vehicle with fewer drives gets empty ones (mask 0, no data);
* the parameters are stacked too (one Params per vehicle); each stage's objective
  ``loss.forward_value_grad_gn`` is ``vmap``-ed over the vehicles and jitted once, with the
  drives passed as arguments (never closed over: a closed-over batch becomes a constant that
  takes a minute to compile);
* ``fleet_optimize.minimize_batch`` runs one L-BFGS per vehicle (one optax state each).

Derivatives are always forward mode (one ``vmap`` of ``jax.jvp`` over the fitted coordinates):
with a handful of keys it costs about the forward pass times the number of keys, stores no
per-step residuals (reverse mode stores the scan's carry for every sample of every drive of every
vehicle, 85 GB at 4096 drives x 9000 samples), and yields the Gauss-Newton Hessian that the
standard errors need.  See docs/fleet.md.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import loss as L
from . import report as R
from .drive_log import bucket_length, pad_inputs  # the length buckets and padding rules live in drive_log

EVAL_FIELDS = ("heading", "wheel_heading", "curvature", "effective_track", "speed", "a", "distance",
               "compass_heading", "compass_valid", "odometer_valid")


@dataclass
class VehicleData:
    """One vehicle's checked drives (``drive_log.Drive``)."""

    vehicle_id: str
    train: list
    validate: list = field(default_factory=list)


@dataclass
class FitOptions:
    mode: str = "odometer"
    max_iter: int = 400
    refine_a: bool = True
    calibration: bool = False
    track: str = "closed_form"
    increment_s: float = 30.0
    gtol: float = 1e-3
    ftol: float = 1e-7
    decorrelation_s: float = L.DEFAULT_DECORRELATION_S
    direction: str = "gauss-newton"     # fleet_optimize.DIRECTIONS
    warm_increment_s: float = 5.0       # > 0: odometer stage first fitted over this increment (continuation)


def pad_batch(inputs, mask, ref, n: int):
    """Extend (B, n0) arrays to (B, n): the inputs by ``drive_log.pad_inputs``, mask and ref with zeros."""
    pad = n - mask.shape[-1]
    if pad <= 0:
        return inputs, mask, ref
    zeros = np.zeros((mask.shape[0], pad))
    return pad_inputs(inputs, n), np.concatenate([mask, zeros], axis=1), np.concatenate([ref, zeros], axis=1)


def stack_vehicles(groups: list[list], n: int | None = None):
    """(inputs (V, D, N), ref (V, D, N), mask (V, D, N), counts (V,)) from V lists of drives.

    D is the largest list; shorter lists are filled with copies of their first drive under mask 0.
    N is ``bucket_length`` of the longest drive unless given."""
    import jax

    from .drive_log import stack_drives, stack_reference

    V = len(groups)
    D = max(len(g) for g in groups)
    flat, real = [], []
    for g in groups:
        flat += list(g) + [g[0]] * (D - len(g))
        real += [1.0] * len(g) + [0.0] * (D - len(g))
    inputs, mask = stack_drives(flat)
    ref, rmask = stack_reference(flat)
    mask = mask * rmask * np.asarray(real)[:, None]
    n = bucket_length(mask.shape[-1]) if n is None else n
    inputs, mask, ref = pad_batch(inputs, mask, ref, n)
    shape = (V, D, n)
    inputs = jax.tree_util.tree_map(lambda a: np.asarray(a).reshape(shape), inputs)
    return inputs, ref.reshape(shape), mask.reshape(shape), np.array([len(g) for g in groups])


_CACHE: dict = {}


def _stage_function(template: L.StageProblem, has_prev: bool, has_sw: bool):
    """jit(vmap over vehicles) of loss.forward_value_grad_gn for this stage's template (cached)."""
    import jax

    sp = template.space
    key = ("stage", sp.keys, sp.transforms, sp.u0.tobytes(), sp.s.tobytes(), sp._scale().tobytes(), template.config,
           template.field_name, template.align, template.lag, has_prev, has_sw)
    if key not in _CACHE:
        def one(z, base, inputs, ref, mask, n_eff, prev, sw):
            prob = dataclasses.replace(template, base=base, inputs=inputs, ref=ref, mask=mask, n_eff=n_eff,
                                       prev=prev, sample_weight=sw)
            return L.forward_value_grad_gn(prob)(z)

        _CACHE[key] = jax.jit(jax.vmap(one))
    return _CACHE[key]


def _to_params_function(space):
    import jax

    key = ("to_params", space.keys, space.transforms, space.u0.tobytes(), space.s.tobytes(), space._scale().tobytes())
    if key not in _CACHE:
        _CACHE[key] = jax.jit(jax.vmap(space.to_params))
    return _CACHE[key]


def evaluator(config, fields=EVAL_FIELDS):
    """jit(vmap over vehicles) of loss.batch_outputs: (stacked Params, Inputs (V, D, N)) -> fields + initialized."""
    import jax

    key = ("eval", config, tuple(fields))
    if key not in _CACHE:
        _CACHE[key] = jax.jit(jax.vmap(lambda p, inp: L.batch_outputs(p, inp, config, fields)))
    return _CACHE[key]


def stacked_params(params_list):
    """One Params whose leaves have a leading vehicle axis."""
    import jax
    import jax.numpy as jnp

    return jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *params_list)


def unstack_params(stacked, v: int):
    import jax

    return jax.tree_util.tree_map(lambda x: np.asarray(x)[v], stacked)


def _ev_dicts(out, inputs, ref, mask, counts, fields=EVAL_FIELDS):
    """Per vehicle, the dict identify's _Evaluator returns (drives sliced to the vehicle's own)."""
    out = [np.asarray(o) for o in out]
    dicts = []
    for v, c in enumerate(counts):
        d = {k: out[i][v, :c] for i, k in enumerate(fields)}
        d["started"] = out[-1][v, :c]
        d["weight"] = mask[v, :c] * (out[-1][v, :c] > 0.5)
        d["ref"] = ref[v, :c]
        d["time_s"] = np.asarray(inputs.time_s)[v, :c]
        dicts.append(d)
    return dicts


def _stage_arrays(stage, inputs, mask, start, decorrelation_s):
    """(n_eff (V, D), prev or None, sample weight or None) as identify computes them, per vehicle."""
    V, D, N = mask.shape
    t = np.asarray(inputs.time_s).reshape(V * D, N)
    m = mask.reshape(V * D, N)
    prev = sw = None
    if stage.lag_m > 0:
        import jax

        flat = jax.tree_util.tree_map(lambda a: np.asarray(a).reshape(V * D, N), inputs)
        dist = L.travelled_distance(flat, start)
        prev = L.increment_index(dist, stage.lag_m)
        ds = np.diff(dist, axis=-1, prepend=dist[..., :1])
        sw = ds.reshape(V, D, N)
        n_eff = np.where(m.sum(-1) > 0, np.maximum(np.sum(m * ds, axis=-1) / stage.lag_m, 1.0), 0.0)
    elif stage.lag_s > 0:
        prev = L.increment_index(t, stage.lag_s)
        n_eff = L.effective_counts(t, m, stage.lag_s)
    else:
        n_eff = L.effective_counts(t, m, decorrelation_s)
    return n_eff.reshape(V, D), (None if prev is None else prev.reshape(V, D, N)), sw


def fit_group(vehicles: list[VehicleData], start, keys, options: FitOptions, active=None, progress=None) -> list[dict]:
    """Identify each vehicle of the group; returns one dict per vehicle:
    {vehicle_id, status: 'ok'|'warning'|'error', params (JSON dict) or None, report, error}.

    ``active`` (V,) bool marks padding vehicles (False: fitted along, result dropped).
    ``progress(n)`` is called with the number of batched iterations done."""
    import jax
    import jax.numpy as jnp

    import jaxmodel

    from .identify import plan_stages

    t0 = time.perf_counter()
    V = len(vehicles)
    active = np.ones(V, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    keys = L.parse_fit(keys)
    inputs, ref, mask, counts = stack_vehicles([v.train for v in vehicles])
    train = (inputs, jax.tree_util.tree_map(jnp.asarray, inputs), ref, mask)
    evaluate = _group_evaluator(vehicles, options)
    current = stacked_params([start] * V)
    ev_before = evaluate(current)

    per_vehicle = [dict(param_rows={}, stage_reports=[], corr_labels=[], corr_blocks=[], warnings=[], iters=0,
                        evals=0) for _ in range(V)]
    failed = np.zeros(V, dtype=bool)
    errors = [None] * V
    callback = (lambda it, n: progress(1)) if progress else None
    for stage in plan_stages(keys, options.mode, options.increment_s):
        t_stage = time.perf_counter()
        space = L.make_space(stage.keys, start, all_keys=keys)
        act = active & ~failed
        fit = _fit_stage(stage, space, current, train, start, act, options, callback)
        for v in np.flatnonzero(act & fit.res.failed):
            failed[v] = True
            errors[v] = f"stage '{stage.name}': {fit.res.reason[v]}"
        current = _to_params_function(space)(jnp.asarray(fit.z_final), current)
        for v in np.flatnonzero(active & ~failed):
            _record_stage(per_vehicle[v], v, stage, space, fit, counts[v], options, t_stage)

    ev_after = evaluate(current)
    wall = time.perf_counter() - t0
    results = []
    for v, veh in enumerate(vehicles):
        if not active[v]:
            continue
        if failed[v]:
            results.append(dict(vehicle_id=veh.vehicle_id, status="error", params=None, report=None,
                                error=errors[v]))
            continue
        fitted = unstack_params(current, v)
        report = _report(veh, start, fitted, keys, options, per_vehicle[v], ev_before[v], ev_after[v], wall, V)
        results.append(dict(vehicle_id=veh.vehicle_id, status="warning" if report["warnings"] else "ok",
                            params=jaxmodel.params_to_dict(fitted), report=report, error=None, fitted=fitted))
    return results


def _group_evaluator(vehicles: list[VehicleData], options: FitOptions):
    """``evaluate(stacked Params)``: per vehicle, the _ev_dicts of its training and validation drives run
    with the fitted mode's estimator (kalman, else complementary)."""
    import jax
    import jax.numpy as jnp

    import jaxmodel

    e_inputs, e_ref, e_mask, e_counts = stack_vehicles([v.train + v.validate for v in vehicles])
    e_inputs_j = jax.tree_util.tree_map(jnp.asarray, e_inputs)
    eval_mode = "kalman" if options.mode == "kalman" else "complementary"
    eval_config = jaxmodel.Config(mode=eval_mode, refine_a=options.refine_a, calibration=options.calibration,
                                  track=options.track)
    ev = evaluator(eval_config)

    def evaluate(params):
        return _ev_dicts(jax.device_get(ev(params, e_inputs_j)), e_inputs, e_ref, e_mask, e_counts)

    return evaluate


@dataclass
class _StageFit:
    """One stage's batched fit of the group: the optimiser runs and, per vehicle, the verdicts."""

    res: Any              # the fit (fleet_optimize.BatchResult)
    res2: Any             # the refit with the non-identifiable coordinates frozen, or None
    warm: Any             # the continuation fit over warm_increment_s, or None
    refit: np.ndarray     # (V,) bool: refitted (res2 is its final fit)
    frozen: np.ndarray    # (V, dim) bool: not identifiable, kept at the start value
    z_final: np.ndarray   # (V, dim) whitened coordinates fitted
    lap: list             # per vehicle R.laplace: the fit's ratios, the refit's errors when refitted
    signal: np.ndarray    # (V, dim) bool: the drives inform the coordinate
    status: list          # per vehicle, per coordinate: R.verdict
    n_eff: np.ndarray     # (V, D) effective errors per drive

    def counts(self, v) -> tuple[int, int]:
        """(iterations, evaluations) of vehicle ``v`` over the warm start, the fit and the refit."""
        use2 = bool(self.refit[v])
        iters = int(self.res.iterations[v]) + (int(self.res2.iterations[v]) if use2 else 0)
        evals = int(self.res.evaluations[v]) + (int(self.res2.evaluations[v]) if use2 else 0)
        if self.warm is not None:
            iters += int(self.warm.iterations[v])
            evals += int(self.warm.evaluations[v])
        return iters, evals

    def outcome(self, v) -> tuple[bool, str]:
        """(converged, stop reason) of vehicle ``v``'s last run (the refit when refitted)."""
        last = self.res2 if self.refit[v] else self.res
        return bool(last.converged[v]), last.reason[v]


def _fit_stage(stage, space, current, train, start, act, options: FitOptions, callback) -> _StageFit:
    """Fit one stage for the vehicles ``act``: warm start, fit, Laplace verdicts, then the refit of the
    vehicles with some (not all) coordinates not identifiable."""
    from .fleet_optimize import minimize_batch

    fn, args, n_eff, prev = _stage_objective(stage, space, current, train, start, options)

    def fun(z, args=args, fn=fn):
        return fn(z, *args)

    z0 = np.zeros((act.size, space.dim))
    warm = None
    if prev is not None and stage.lag_s > options.warm_increment_s > 0:
        warm = _warm_fit(stage, fn, args, z0, train, start, act, options, callback)
        z0 = np.where((act & ~warm.failed)[:, None], warm.z, 0.0)
    res = minimize_batch(fun, z0, active=act, max_iter=options.max_iter, gtol=options.gtol, ftol=options.ftol,
                         direction=options.direction, callback=callback)
    lap, signal, status, frozen = _verdicts(res, space)
    refit = act & ~res.failed & frozen.any(axis=1) & ~frozen.all(axis=1)  # failed vehicles are not refitted
    z_final = res.z.copy()
    z_final[act & frozen.all(axis=1)] = 0.0
    res2 = None
    if refit.any():  # keep them at the start value (z = 0) and re-optimise the others around that
        z_fix = np.where(frozen, 0.0, res.z)
        res2 = minimize_batch(
            fun, z_fix, active=refit, frozen=frozen, max_iter=options.max_iter, gtol=options.gtol,
            ftol=options.ftol, direction=options.direction, callback=callback)
        z_final[refit] = res2.z[refit]
        for v in np.flatnonzero(refit):  # identify keeps the first fit's ratios (the verdicts), the refit's errors
            _, _, se2, corr2 = R.laplace(res2.extra[0][v], space.dtheta_dz(res2.z[v]))
            lap[v] = (None, lap[v][1], se2, corr2)
    return _StageFit(res, res2, warm, refit, frozen, z_final, lap, signal, status, n_eff)


def _stage_objective(stage, space, current, train, start, options: FitOptions):
    """(fn, args, n_eff, prev): the stage's batched objective is ``fn(z, *args)``; prev is None unless the
    stage fits heading changes."""
    import jax.numpy as jnp

    import jaxmodel

    inputs, j_inputs, ref, mask = train
    cfg = jaxmodel.Config(mode=stage.mode, refine_a=options.refine_a, calibration=options.calibration,
                          track=options.track)
    n_eff, prev, sw = _stage_arrays(stage, inputs, mask, start, options.decorrelation_s)
    template = L.StageProblem(space, None, None, None, None, cfg, stage.field_name, stage.align, None, 0, None, None)
    fn = _stage_function(template, prev is not None, sw is not None)
    args = (current, j_inputs, jnp.asarray(ref), jnp.asarray(mask), jnp.asarray(n_eff),
            None if prev is None else jnp.asarray(prev), None if sw is None else jnp.asarray(sw))
    return fn, args, n_eff, prev


def _warm_fit(stage, fn, args, z0, train, start, act, options: FitOptions, callback):
    """The continuation fit: the stage's program over heading changes of ``warm_increment_s``."""
    import jax.numpy as jnp

    from .fleet_optimize import minimize_batch

    # continuation: heading changes over a few seconds first (same program, other indices), whose
    # errors stay far below pi even with a 1 % dpp mismatch; over 30 s they can wrap, and there
    # 1 - cos is flat: a start far from the truth would stall (measured: 1 of 8 vehicles)
    inputs, _, _, mask = train
    w_stage = dataclasses.replace(stage, lag_s=options.warm_increment_s)
    w_neff, w_prev, _ = _stage_arrays(w_stage, inputs, mask, start, options.decorrelation_s)
    w_args = args[:4] + (jnp.asarray(w_neff), jnp.asarray(w_prev)) + args[6:]
    return minimize_batch(lambda z: fn(z, *w_args), z0, active=act, max_iter=options.max_iter,
                          gtol=options.gtol, ftol=options.ftol, direction=options.direction, callback=callback)


def _verdicts(res, space):
    """(lap, signal, status, frozen) per vehicle from the fit's Gauss-Newton Hessian: R.laplace, whether
    the drives inform each coordinate, its R.verdict, and the coordinates not identifiable."""
    hess = res.extra[0]
    V = res.z.shape[0]
    dz = [space.dtheta_dz(res.z[v]) for v in range(V)]
    lap = [R.laplace(hess[v], dz[v]) for v in range(V)]
    signal = np.diagonal(hess, axis1=1, axis2=2) - 1.0 > 1e-9  # (V, dim)
    status = [[R.verdict(float(r), bool(s)) for r, s in zip(lap[v][1], signal[v])] for v in range(V)]
    frozen = np.array([[s == "not identifiable" for s in status[v]] for v in range(V)])
    return lap, signal, status, frozen


def _record_stage(pv, v, stage, space, fit: _StageFit, n_drives, options: FitOptions, t_stage) -> None:
    """Add vehicle ``v``'s results of the stage to its report parts ``pv`` (see fit_group)."""
    iters, evals = fit.counts(v)
    pv["iters"] += iters
    pv["evals"] += evals
    pv["param_rows"].update(_parameter_rows(v, stage, space, fit))
    pv["corr_labels"].extend(space.labels)
    pv["corr_blocks"].append(fit.lap[v][3])
    conv, why = fit.outcome(v)
    pv["stage_reports"].append(_stage_report(v, stage, space, fit, n_drives, iters, evals, options, t_stage))
    if not conv:
        pv["warnings"].append(f"stage '{stage.name}' did not converge: {why}")


def _parameter_rows(v, stage, space, fit: _StageFit) -> dict[str, dict]:
    """Report rows of the stage's parameters for vehicle ``v`` (identify's "parameters" entries)."""
    from .identify import parameter_rows

    _, ratio, se, _ = fit.lap[v]
    return parameter_rows(space, stage.name, fit.z_final[v], se, ratio, fit.signal[v], fit.status[v])


def _stage_report(v, stage, space, fit: _StageFit, n_drives, iters, evals, options: FitOptions, t_stage) -> dict:
    """Vehicle ``v``'s entry of the report's "stages" list (identify's keys)."""
    use2 = bool(fit.refit[v])
    conv, why = fit.outcome(v)
    return {
        "name": stage.name, "keys": list(stage.keys), "heading": stage.field_name,
        "estimator_mode": stage.mode,
        "loss": (f"1 - cos of the heading change error over {stage.lag_s:g} s" if stage.lag_s > 0
                 else "1 - cos of the absolute heading error" + (" (per-drive offset removed)" if stage.align else "")),
        "effective_errors_per_drive": [float(x) for x in fit.n_eff[v, :n_drives]],
        "derivatives": "forward (vmapped over the vehicles of the group)",
        "iterations": iters, "evaluations": evals, "converged": conv, "stop_reason": why,
        "loss_history": fit.res.history[v], "loss_history_refit": fit.res2.history[v] if use2 else [],
        "refit_with_fixed": [space.labels[j] for j in np.flatnonzero(fit.frozen[v])] if use2 else [],
        "warm_start": (f"fitted first over {options.warm_increment_s:g}-s heading changes "
                       f"({int(fit.warm.iterations[v])} iterations)") if fit.warm is not None else None,
        "wall_time_s_group": time.perf_counter() - t_stage,
    }


def rmse_rows(ev_before, ev_after, drives, roles, mode) -> list[dict]:
    """Per drive: heading RMSE (deg) before and after, of the odometer heading (also offset removed)
    and of the filtered heading; ``rmse_*_deg`` is the fitted mode's (identify's report rows)."""
    rows = []
    primary = "wheel_heading" if mode == "odometer" else "heading"
    est_name = "kalman" if mode == "kalman" else "complementary"
    for b, (d, role) in enumerate(zip(drives, roles)):
        t = np.asarray(d.inputs.time_s)
        row: dict[str, Any] = {"role": role, "name": d.path, "n_samples": int(t.size),
                               "duration_s": float(t[-1] - t[0])}
        for tag, ev in (("before", ev_before), ("after", ev_after)):
            w = ev["weight"][b]
            e_odo = ev["wheel_heading"][b] - ev["ref"][b]
            row[f"odometer_rmse_{tag}_deg"] = R.rmse_deg(e_odo, w)
            row[f"odometer_rmse_offset_removed_{tag}_deg"] = R.rmse_deg(e_odo, w, align=True)
            row[f"{est_name}_rmse_{tag}_deg"] = R.rmse_deg(ev["heading"][b] - ev["ref"][b], w)
            row[f"rmse_{tag}_deg"] = R.rmse_deg(ev[primary][b] - ev["ref"][b], w)
        rows.append(row)
    return rows


def _drive_warnings(veh, start, ev) -> list[str]:
    """diagnostics.drive_warnings of each drive, from the batched run with the start parameters."""
    from .diagnostics import drive_warnings
    from .drive_log import wrap_deg

    out = []
    for b, d in enumerate(veh.train + veh.validate):
        n = len(np.asarray(d.inputs.time_s))
        cols = {"time_s": np.asarray(d.inputs.time_s, dtype=np.float64),
                "heading_deg": wrap_deg(np.rad2deg(ev["heading"][b, :n])),
                "compass_heading_deg": wrap_deg(np.rad2deg(ev["compass_heading"][b, :n])),
                "compass_valid": ev["compass_valid"][b, :n], "odometer_valid": ev["odometer_valid"][b, :n]}
        out += drive_warnings(d, start, cols)
    return out


def _report(veh, start, fitted, keys, options, pv, ev_before, ev_after, wall, group_size) -> dict[str, Any]:
    """identify's report for one vehicle of the group (same keys; see identification.identify)."""
    from .identify import KEY_HINTS

    n_train = len(veh.train)
    drives = veh.train + veh.validate
    roles = ["train"] * n_train + ["validate"] * len(veh.validate)
    rows = rmse_rows(ev_before, ev_after, drives, roles, options.mode)
    warnings = list(pv["warnings"])
    params = pv["param_rows"]
    warnings += R.identifiability_warnings(params, R.identifiability_context(ev_after, n_train), KEY_HINTS)
    labels = pv["corr_labels"]
    full = R.block_correlation(labels, pv["corr_blocks"])
    for a_, b_, c_ in R.correlated_pairs(labels, np.nan_to_num(full)):
        warnings.append(f"{a_} and {b_} are {abs(c_):.3f} {'correlated' if c_ > 0 else 'anti-correlated'}: "
                        f"the drives identify a combination of them, not each one")

    return {
        "fit": list(keys), "mode": options.mode,
        "rmse_heading": "odometer-only heading" if options.mode == "odometer" else f"{options.mode} heading",
        "config": {"refine_a": bool(options.refine_a), "calibration": bool(options.calibration), "track": options.track},
        "optimizer": (("Gauss-Newton directions (forward-mode GN Hessian)" if options.direction == "gauss-newton"
                       else "optax.scale_by_lbfgs (memory 10, one state per vehicle)")
                      + " + backtracking Armijo line search, whitened unconstrained coordinates, MAP prior "
                        "N(start, prior_std); vehicles batched with vmap (identification.fleet_optimize)"),
        "convergence": {"gtol": options.gtol, "ftol": options.ftol, "max_iter": options.max_iter},
        "decorrelation_s": options.decorrelation_s, "increment_s": options.increment_s,
        "parameters": params,
        "correlation": {"parameters": labels,
                        "matrix": [[None if not math.isfinite(x) else round(float(x), 6) for x in r] for r in full],
                        "note": "null: stages are fitted one after the other; cross-stage correlations are not estimated"},
        "effective_track": R.effective_track_table(start, fitted),
        "drives": rows, "stages": pv["stage_reports"], "iterations": pv["iters"], "evaluations": pv["evals"],
        "drive_warnings": _drive_warnings(veh, start, ev_before),
        "warnings": warnings,
        "group": {"vehicles": int(group_size), "wall_time_s": wall},
    }
