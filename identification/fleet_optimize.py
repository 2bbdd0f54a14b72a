"""The fleet's optimiser: ``identification.optimize.minimize`` for many vehicles at once.

Each vehicle keeps its own coordinates z_v, its own ``optax.scale_by_lbfgs`` state (the optax
state is vmapped: one memory of curvature pairs per vehicle), its own step length and its own
convergence test, exactly the rules of ``optimize.minimize`` (Armijo backtracking, ``max_step``
prior standard deviations per step, L-BFGS restart on non-positive curvature, gtol / ftol /
precision-limit stops).  What the vehicles share is the objective evaluation: ``fun`` maps the
stacked coordinates (V, dim) to stacked values, gradients and extras in *one* compiled call
(``jit(vmap(...))`` over the vehicles), so a line-search trial costs one batched call whatever
the number of vehicles still searching.  A vehicle that has converged (or is inactive) keeps its
coordinates; its lanes are still computed, and ignored.

Two search directions, the line search and stopping rules being the same:

* ``gauss-newton`` (the fleet's default): d = H^-1 g with the Gauss-Newton Hessian H that the
  forward-mode objective returns with every evaluation anyway (``loss.forward_value_grad_gn``).
  The objective is a profiled sum of squared residuals plus the prior, so H is the right metric:
  measured on two vehicles (2 x 5-minute drives, P,B,T_F,a,T_C,D_N,dpp_right) the same optima in
  14 and 39 iterations against 43 and 115 for L-BFGS, 4.9 s against 36.6 s for the pair.  The
  stiff direction that slows L-BFGS down (dpp_right against T_F, prior 2 % but fixed by the data
  to 0.01 %) is exactly what H knows.
* ``lbfgs``: ``identify``'s optimiser, ``optax.scale_by_lbfgs`` (memory 10) per vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax


@dataclass
class BatchResult:
    z: np.ndarray                 # (V, dim)
    value: np.ndarray             # (V,)
    grad: np.ndarray              # (V, dim)
    extra: tuple                  # each (V, ...)
    iterations: np.ndarray        # (V,) int
    evaluations: np.ndarray       # (V,) int: batched calls in which this vehicle was searching
    converged: np.ndarray         # (V,) bool
    reason: list                  # (V,) str
    history: list = field(default_factory=list)  # per vehicle: objective after each iteration
    failed: np.ndarray | None = None  # (V,) bool: objective not finite at the start (reason says so)


def _select(mask, new, old):
    """Per-vehicle choice between two stacked pytrees (mask (V,) bool)."""
    m = jnp.asarray(mask)

    def pick(a, b):
        a, b = jnp.asarray(a), jnp.asarray(b)
        return jnp.where(m.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)

    return jax.tree_util.tree_map(pick, new, old)


DIRECTIONS = ("gauss-newton", "lbfgs")


def _solve(h, g):
    """Per vehicle h_v^-1 g_v; a singular or non-finite system gives NaN (then steepest descent)."""
    out = np.full(g.shape, np.nan)
    for v in range(g.shape[0]):
        try:
            if np.all(np.isfinite(h[v])):
                out[v] = np.linalg.solve(h[v], g[v])
        except np.linalg.LinAlgError:
            pass
    return out


_OPTAX_CACHE: dict = {}


def _lbfgs(memory: int):
    """(init, update) of optax.scale_by_lbfgs, vmapped over vehicles and jitted (cached per process)."""
    if memory not in _OPTAX_CACHE:
        opt = optax.scale_by_lbfgs(memory_size=memory)
        _OPTAX_CACHE[memory] = (jax.jit(jax.vmap(opt.init)), jax.jit(jax.vmap(opt.update)))
    return _OPTAX_CACHE[memory]


@dataclass
class _Search:
    """The batched search's state, one lane per vehicle (mutated by the helpers below)."""
    z: np.ndarray                 # (V, dim) current coordinates
    value: np.ndarray             # (V,)
    grad: np.ndarray              # (V, dim), zero on the frozen coordinates
    extra: tuple                  # each (V, ...); extra[0] the Gauss-Newton Hessian
    state: Any                    # the vmapped optax L-BFGS state
    done: np.ndarray              # (V,) bool: stopped (converged, stalled, failed or inactive)
    converged: np.ndarray         # (V,) bool
    small: np.ndarray             # (V,) int: consecutive iterations that changed the objective by < ftol
    iterations: np.ndarray        # (V,) int
    evaluations: np.ndarray       # (V,) int
    reason: list                  # (V,) str
    history: list                 # per vehicle: objective after each iteration


class _Trial(NamedTuple):
    """The line search's outcome: which vehicles found a decrease, and where (the old values elsewhere)."""
    accepted: np.ndarray
    z: np.ndarray
    value: np.ndarray
    grad: np.ndarray
    extra: tuple


def _evaluate(fun: Callable, free, zz):
    """(value, grad, extra) of ``fun`` at the stacked ``zz`` as float64 NumPy, the gradient zero where frozen."""
    o = jax.device_get(fun(jnp.asarray(zz)))
    g = np.where(free, np.asarray(o[1], dtype=np.float64), 0.0)
    return np.asarray(o[0], dtype=np.float64), g, tuple(np.asarray(e) for e in o[2:])


def _finish(s: _Search, mask, reason: str) -> None:
    """The vehicles ``mask`` stop, converged, for ``reason``."""
    for v in np.flatnonzero(mask):
        s.reason[v] = reason
    s.converged |= mask
    s.done |= mask


def _start(evaluate: Callable, z, active, gtol: float, init: Callable) -> tuple[_Search, np.ndarray]:
    """(search state, failed) at z0: the vehicles whose objective is not finite there fail, those whose
    gradient is already below gtol have converged."""
    V = z.shape[0]
    value, grad, extra = evaluate(z)
    evaluations = active.astype(np.int64)
    failed = active & ~(np.isfinite(value) & np.all(np.isfinite(grad), axis=1))
    reason = ["inactive"] * V
    for v in np.flatnonzero(failed):
        reason[v] = "the objective is not finite at the starting parameters"
    history = [[float(value[v])] for v in range(V)]
    s = _Search(z, value, grad, extra, None, ~active | failed, np.zeros(V, dtype=bool), np.zeros(V, dtype=np.int64),
                np.zeros(V, dtype=np.int64), evaluations, reason, history)
    _finish(s, ~s.done & (np.max(np.abs(grad), axis=1) <= gtol), f"gradient below gtol={gtol:g}")
    s.state = init(jnp.asarray(z))
    return s, failed


def _gauss_newton_step(free, grad, hessian):
    """d = H^-1 g with the Gauss-Newton Hessian on the free block (identity on the frozen coordinates)."""
    dim = free.shape[1]
    h = np.where(free[:, :, None] & free[:, None, :], hessian, 0.0) + np.eye(dim)[None] * (~free)[:, None, :]
    return np.where(free, _solve(h, grad), 0.0)


def _lbfgs_step(update: Callable, free, grad, state, z):
    """(d, new optax state): the L-BFGS direction, zero on the frozen coordinates."""
    d, new_state = update(jnp.asarray(grad), state, jnp.asarray(z))
    return np.where(free, np.asarray(d, dtype=np.float64), 0.0), new_state


def _direction(s: _Search, searching, free, gn: bool, init: Callable, update: Callable):
    """(d, slope, new_state): each vehicle's search direction (the step is -alpha d), its slope -g.d and
    the L-BFGS state after it.  Where d is not a descent direction: steepest descent (Gauss-Newton), or
    a restart of that vehicle's L-BFGS memory (``s.state`` reset there)."""
    if gn:  # d = H^-1 g, the Gauss-Newton Hessian (extra[0]) on the free block
        d, new_state = _gauss_newton_step(free, s.grad, s.extra[0]), s.state
    else:
        d, new_state = _lbfgs_step(update, free, s.grad, s.state, s.z)
    slope = -np.sum(s.grad * d, axis=1)
    restart = searching & ~((slope < 0.0) & np.all(np.isfinite(d), axis=1))
    if gn and restart.any():  # steepest descent where the GN system failed
        d = np.where(restart[:, None], np.where(free, s.grad, 0.0), d)
        slope = -np.sum(s.grad * d, axis=1)
    elif restart.any():  # not a descent direction: restart those vehicles' memory
        s.state = _select(restart, init(jnp.asarray(s.z)), s.state)
        d2, state2 = _lbfgs_step(update, free, s.grad, s.state, s.z)
        d = np.where(restart[:, None], d2, d)
        new_state = _select(restart, state2, new_state)
        slope = -np.sum(s.grad * d, axis=1)
    return d, slope, new_state


def _line_search(evaluate: Callable, s: _Search, searching, d, slope, max_step: float, c1: float,
                 max_backtracks: int) -> _Trial:
    """Armijo backtracking along -d for the searching vehicles, all trials of an iteration batched; the
    first step at most ``max_step`` long.  Counts each vehicle's evaluations in ``s.evaluations``."""
    norm = np.linalg.norm(d, axis=1)
    alpha = np.where(norm > 0, np.minimum(1.0, max_step / np.where(norm > 0, norm, 1.0)), 1.0)
    accepted = np.zeros(s.z.shape[0], dtype=bool)
    z_new, v_new, g_new = s.z.copy(), s.value.copy(), s.grad.copy()
    e_new = tuple(e.copy() for e in s.extra)
    for _ in range(max_backtracks):
        trying = searching & ~accepted
        if not trying.any():
            break
        z_try = np.where(trying[:, None], s.z - alpha[:, None] * d, s.z)
        v_try, g_try, x_try = evaluate(z_try)
        s.evaluations += trying
        ok = trying & np.isfinite(v_try) & np.all(np.isfinite(g_try), axis=1) \
            & (v_try <= s.value + c1 * alpha * slope)
        z_new[ok], v_new[ok], g_new[ok] = z_try[ok], v_try[ok], g_try[ok]
        for e_n, e_t in zip(e_new, x_try):
            e_n[ok] = e_t[ok]
        accepted |= ok
        alpha = np.where(trying & ~ok, 0.5 * alpha, alpha)
    return _Trial(accepted, z_new, v_new, g_new, e_new)


def _take_steps(s: _Search, moved, trial: _Trial, new_state):
    """Move the vehicles ``moved`` to their accepted trial (and L-BFGS state); (objective decrease,
    curvature s.y of the step) per vehicle."""
    s.iterations += moved
    s_vec = trial.z - s.z
    y_vec = trial.grad - s.grad
    change = s.value - trial.value
    s.state = _select(moved, new_state, s.state)
    s.z, s.value, s.grad = np.where(moved[:, None], trial.z, s.z), np.where(moved, trial.value, s.value), \
        np.where(moved[:, None], trial.grad, s.grad)
    s.extra = tuple(np.where(moved.reshape((-1,) + (1,) * (e.ndim - 1)), en, e) for en, e in zip(trial.extra, s.extra))
    for v in np.flatnonzero(moved):
        s.history[v].append(float(s.value[v]))
    return change, np.sum(s_vec * y_vec, axis=1)


def _stop_tests(s: _Search, moved, change, ftol: float, gtol: float) -> None:
    """After a step: stop on a change below ftol over two iterations, else on the gradient below gtol."""
    s.small = np.where(moved, np.where(change < ftol, s.small + 1, 0), s.small)
    f_stop = moved & (s.small >= 2)
    g_stop = moved & ~f_stop & (np.max(np.abs(s.grad), axis=1) <= gtol)
    _finish(s, f_stop, f"objective changed by less than ftol={ftol:g} over two iterations")
    _finish(s, g_stop, f"gradient below gtol={gtol:g}")


def minimize_batch(fun: Callable, z0, *, active=None, frozen=None, max_iter: int = 400, gtol: float = 1e-3,
                   ftol: float = 1e-7, max_step: float = 2.0, memory: int = 10, c1: float = 1e-4,
                   max_backtracks: int = 30, callback: Callable | None = None,
                   direction: str = "lbfgs") -> BatchResult:
    """Minimize V independent objectives stacked in ``fun``: z (V, dim) -> (value (V,), grad (V, dim), *extra).

    ``active`` (V,) bool: vehicles to optimise (the others keep z0 and count no iterations);
    ``frozen`` (V, dim) bool: coordinates held at z0.  ``callback(iteration, n_searching)`` after
    every batched iteration.  A vehicle whose objective is not finite at z0 is reported
    ``failed`` (it is never moved) instead of raising, so the others go on.
    """
    z = np.array(z0, dtype=np.float64)
    V, dim = z.shape
    active = np.ones(V, dtype=bool) if active is None else np.asarray(active, dtype=bool).copy()
    free = np.ones((V, dim), dtype=bool) if frozen is None else ~np.asarray(frozen, dtype=bool)
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
    gn = direction == "gauss-newton"
    init, update = _lbfgs(memory)

    def evaluate(zz):
        return _evaluate(fun, free, zz)

    s, failed = _start(evaluate, z, active, gtol, init)
    for iteration in range(1, max_iter + 1):
        if s.done.all():
            break
        searching = ~s.done
        d, slope, new_state = _direction(s, searching, free, gn, init, update)
        trial = _line_search(evaluate, s, searching, d, slope, max_step, c1, max_backtracks)
        _finish(s, searching & ~trial.accepted, "no decrease along the search direction (precision limit)")
        moved = searching & trial.accepted
        change, curvature = _take_steps(s, moved, trial, new_state)
        bad_curv = moved & (curvature <= 0.0)
        if bad_curv.any() and not gn:  # curvature pair unusable: restart L-BFGS there
            s.state = _select(bad_curv, init(jnp.asarray(s.z)), s.state)
        _stop_tests(s, moved, change, ftol, gtol)
        if callback is not None:
            callback(iteration, int((~s.done).sum()))
    for v in np.flatnonzero(~s.done):
        s.reason[v] = f"reached max_iter={max_iter} without meeting the convergence criteria"
    return BatchResult(s.z, s.value, s.grad, s.extra, s.iterations, s.evaluations, s.converged, s.reason, s.history,
                       failed)
