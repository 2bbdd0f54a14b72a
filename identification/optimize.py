"""The optimiser: optax L-BFGS directions with a safeguarded backtracking line search.

Why L-BFGS (``optax.scale_by_lbfgs``)
-------------------------------------
The objective is deterministic, smooth (1 - cos errors, sigmoid/log reparametrisation) and
evaluated on the full batch of drives, with a handful of parameters in whitened coordinates.
That is quasi-Newton territory: L-BFGS converges superlinearly in tens of iterations, needs no
learning rate, and its step length comes from a line search, so the result does not depend on a
schedule.  Adam (even with ``clip_by_global_norm``) needs hundreds of noisy-looking iterations
and a tuned rate to reach the same tolerance, each iteration costing a full pass over every
drive.

Why our own line search around optax's direction
------------------------------------------------
``optax.lbfgs`` chains the direction with a zoom line search that differentiates the
objective itself, inside its own compiled loop.  Here one evaluation runs the estimator over
every sample of every drive and its derivatives come from forward mode (see loss.py), so the
objective is compiled exactly once and called from a Python loop: the line search below only
needs values and gradients at trial points, gives the progress bar a tick per iteration, treats
a non-finite trial value as "too far" (halves the step), caps every step at ``max_step`` prior
standard deviations, and restarts the L-BFGS memory if a step shows non-positive curvature.

Convergence (not a fixed count): stop when the largest gradient component is below ``gtol``
(objective units are nats, coordinates are prior standard deviations), or when the objective
changed by less than ``ftol`` nats over two successive iterations, or when no step along the
direction decreases it any more (the precision limit).  ``max_iter`` only caps a run that does
not converge, which the report then says.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax


@dataclass
class OptResult:
    z: np.ndarray
    value: float
    grad: np.ndarray
    extra: tuple
    iterations: int
    evaluations: int
    converged: bool
    reason: str
    history: list = field(default_factory=list)  # objective after each iteration (index 0: start)


def minimize(fun: Callable, z0, *, max_iter: int = 400, gtol: float = 1e-3, ftol: float = 1e-7,
             max_step: float = 2.0, memory: int = 10, c1: float = 1e-4, max_backtracks: int = 30,
             callback: Callable | None = None, frozen=None) -> OptResult:
    """Minimize ``fun``: z -> (value, grad, *extra) (numpy-convertible) from ``z0``.

    ``callback(iteration, value, grad_inf_norm)`` is called after every iteration.  ``frozen``
    (boolean mask over z) holds those coordinates at their values in ``z0``.
    """
    opt = optax.scale_by_lbfgs(memory_size=memory)
    direction_fn = jax.jit(opt.update)
    free = np.ones(np.shape(z0), dtype=bool) if frozen is None else ~np.asarray(frozen, dtype=bool)

    def evaluate(zz):
        o = fun(zz)
        return float(o[0]), np.where(free, np.asarray(o[1], dtype=np.float64), 0.0), tuple(o[2:])

    z = jnp.asarray(z0, dtype=jnp.float64)
    value, grad, extra = evaluate(z)
    evaluations = 1
    if not np.isfinite(value) or not np.all(np.isfinite(grad)):
        raise FloatingPointError("the objective is not finite at the starting parameters")
    history = [value]
    state = opt.init(z)
    small_steps = 0
    reason = f"reached max_iter={max_iter} without meeting the convergence criteria"
    converged = False
    iteration = 0
    for iteration in range(1, max_iter + 1):
        if np.max(np.abs(grad)) <= gtol:
            reason = f"gradient below gtol={gtol:g}"
            converged = True
            iteration -= 1
            break
        d, state = direction_fn(jnp.asarray(grad), state, z)
        d = np.where(free, np.asarray(d, dtype=np.float64), 0.0)
        slope = -float(np.dot(grad, d))
        if not (slope < 0.0 and np.all(np.isfinite(d))):  # not a descent direction: restart the memory
            state = opt.init(z)
            d, state = direction_fn(jnp.asarray(grad), state, z)
            d = np.where(free, np.asarray(d, dtype=np.float64), 0.0)
            slope = -float(np.dot(grad, d))
        norm = float(np.linalg.norm(d))
        alpha = min(1.0, max_step / norm) if norm > 0 else 1.0
        accepted = False
        for _ in range(max_backtracks):
            z_try = np.asarray(z) - alpha * d
            v_try, g_try, extra_try = evaluate(jnp.asarray(z_try))
            evaluations += 1
            if np.isfinite(v_try) and np.all(np.isfinite(g_try)) and v_try <= value + c1 * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            reason = "no decrease along the search direction (precision limit)"
            converged = True
            iteration -= 1
            break
        s_vec = z_try - np.asarray(z)
        y_vec = g_try - grad
        change = value - v_try
        z, value, grad, extra = jnp.asarray(z_try), v_try, g_try, extra_try
        history.append(value)
        if float(np.dot(s_vec, y_vec)) <= 0.0:  # curvature pair unusable: restart L-BFGS here
            state = opt.init(z)
        if callback is not None:
            callback(iteration, value, float(np.max(np.abs(grad))))
        small_steps = small_steps + 1 if change < ftol else 0
        if small_steps >= 2:
            reason = f"objective changed by less than ftol={ftol:g} over two iterations"
            converged = True
            break
        if np.max(np.abs(grad)) <= gtol:
            reason = f"gradient below gtol={gtol:g}"
            converged = True
            break
    return OptResult(np.asarray(z), value, grad, extra, iteration, evaluations, converged, reason, history)
