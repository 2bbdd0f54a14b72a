"""Cost of one value_and_grad of the identification loss relative to one forward pass, float64,
over a batch of simulated drives, measured side by side in one run (issue 4 target: <= 8x).

    .venv/bin/python bench/bench_grad.py [--minutes 40] [--fit P,B,T_F,a,T_C] [--repeat 5] [--flat]

The batch is the issue's training set: mixed, urban and parking drives sharing ``--minutes``
(20/12/8 minutes by default), padded to one length.  The loss is the one ``identify`` minimises
in its wheel stage (1 - cos of 30 s heading-change errors, MAP prior).  Variants:

* forward pass       jit(loss)                                        -- the reference, 1x
* reverse            jit(value_and_grad(loss)), plain scan
* reverse+checkpoint jit(value_and_grad(loss)), jax.checkpoint on each step (remat: only the
                     carry is stored per step, the step is recomputed in the backward pass)
* forward-mode       one vmap of jax.jvp over the basis of the fitted coordinates: value,
                     gradient *and* the Gauss-Newton Hessian -- what identify uses
* --flat adds reverse mode with the carry ravelled into one vector (ravel_pytree), the layout
  FIELD-NOTES measured at 58x with scalar carries.

Each variant is called ``--repeat`` times, interleaved with the others (a busy spell on a shared
machine hits all alike); best and median are printed, ratios against the forward pass's best and
median.  Compile time is reported apart, and the memory column gives each compiled program's
working memory (XLA's memory analysis) and that figure scaled to 4096 drives x 9000 samples
(issue 13: reverse mode there asked 85 GB of an 80 GB GPU; forward mode stores no residuals).
Everything is float64 (no float32 anywhere in identification).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import jaxmodel  # noqa: E402
from identification import loss as L  # noqa: E402
from identification.drive_log import drive_from_columns, stack_drives, stack_reference  # noqa: E402
from identification.simulate import simulate  # noqa: E402

TRUE = dict(P=0.135, B=2.78, T_F=1.59, a=1.3e-4)


def batch(minutes: float):
    plan = [("mixed", 0.5), ("urban", 0.3), ("parking", 0.2)]
    drives = [drive_from_columns(simulate(sc, minutes * 60.0 * f, seed=i, params=TRUE)[0], source=sc)
              for i, (sc, f) in enumerate(plan)]
    inputs, mask = stack_drives(drives)
    ref, rmask = stack_reference(drives)
    return jax.tree_util.tree_map(jnp.asarray, inputs), ref, mask * rmask


def flat_objective(problem: L.StageProblem):
    """The same objective with the scan carry ravelled into one float64 vector (for comparison)."""
    from jax.flatten_util import ravel_pytree

    from jaxmodel.angles import wrap

    def objective(z):
        p = problem.space.to_params(z, problem.base)
        flat0, unravel = ravel_pytree(jaxmodel.init_state(p))

        def body(flat, sample):
            new, out = jaxmodel.step(p, unravel(flat), sample, problem.config)
            return ravel_pytree(new)[0], (out.wheel_heading, new.initialized)

        h, started = jax.vmap(lambda inp: jax.lax.scan(body, flat0, inp)[1])(problem.inputs)
        e = wrap(h - problem.ref)
        w = jax.lax.stop_gradient(problem.mask * (started > 0.5))
        r, w = L.residuals(e, w, problem.align, problem.lag, problem.prev, problem.sample_weight)
        return L.data_term(r, w, jnp.asarray(problem.n_eff)) + 0.5 * jnp.sum(z * z)

    return objective


def _temp_bytes(fn, z):
    """Working memory (bytes) XLA allocates for one call of the jitted ``fn``, from its compiled
    memory analysis; None where the backend does not report it."""
    try:
        analysis = fn.lower(z).compile().memory_analysis()
        return int(analysis.temp_size_in_bytes)
    except Exception:  # noqa: BLE001 - not every backend/version reports it
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=40.0, help="total minutes over the three drives")
    ap.add_argument("--fit", default="P,B,T_F,a,T_C")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--flat", action="store_true", help="also time reverse mode over a ravelled carry")
    args = ap.parse_args()

    inputs, ref, mask = batch(args.minutes)
    start = jaxmodel.make_params()
    space = L.make_space(L.parse_fit(args.fit), start)
    config = jaxmodel.Config(mode="odometer", calibration=False)
    time_s = np.asarray(inputs.time_s)
    problem = L.StageProblem(space, start, inputs, jnp.asarray(ref), jnp.asarray(mask), config, "wheel_heading",
                             False, L.effective_counts(time_s, mask, 30.0), 0, L.increment_index(time_s, 30.0))
    z = jnp.full((space.dim,), 0.1)
    b, n = inputs.time_s.shape
    print(f"batch: {b} drives x {n} samples (padded) = {b * n:,} estimator steps per pass, float64, "
          f"{space.dim} fitted coordinates ({args.fit}), jax {jax.__version__}, {jax.devices()[0].platform}")

    variants = [
        ("forward pass jit(loss)", jax.jit(lambda zz: problem.objective(zz))),
        ("reverse value_and_grad", jax.jit(jax.value_and_grad(lambda zz: problem.objective(zz, checkpoint=False)))),
        ("reverse + jax.checkpoint per step", L.reverse_value_grad(problem, checkpoint=True)),
        ("forward-mode value+grad+GN Hessian", L.forward_value_grad_gn(problem)),
    ]
    if args.flat:
        variants.append(("reverse, ravelled (flat) carry", jax.jit(jax.value_and_grad(flat_objective(problem)))))

    compile_s = {}
    for name, fn in variants:  # first call: compile + one run; second call: one run
        t0 = time.perf_counter()
        jax.block_until_ready(fn(z))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(fn(z))
        compile_s[name] = max(first - (time.perf_counter() - t0), 0.0)
    runs = {name: [] for name, _ in variants}
    for _ in range(args.repeat):  # interleaved, so a busy spell on the machine hits every variant alike
        for name, fn in variants:
            t0 = time.perf_counter()
            jax.block_until_ready(fn(z))
            runs[name].append(time.perf_counter() - t0)
    results = {name: (compile_s[name], min(r), statistics.median(r)) for name, r in runs.items()}
    memory = {name: _temp_bytes(fn, z) for name, fn in variants}  # after the timings (it compiles again)
    base, base_med = results[variants[0][0]][1], results[variants[0][0]][2]
    print(f"{'variant':38s} {'compile s':>10s} {'best ms':>9s} {'x forward':>10s} {'median ms':>10s} {'x fwd':>6s} "
          f"{'temp MB':>9s} {'GB @4096x9000':>14s}")
    for name, (c, r, m) in results.items():
        mb = memory[name] / 1e6 if memory[name] is not None else float("nan")
        big = memory[name] / (b * n) * 4096 * 9000 / 1e9 if memory[name] is not None else float("nan")
        print(f"{name:38s} {c:10.2f} {r * 1e3:9.1f} {r / base:10.2f} {m * 1e3:10.1f} {m / base_med:6.2f} "
              f"{mb:9.1f} {big:14.1f}")
    print("temp MB: XLA's working memory of the compiled program (compiled.memory_analysis().temp_size_in_bytes: "
          "the scan's stored residuals in reverse mode); GB @4096x9000: that figure scaled linearly to the "
          "issue-13 GPU batch of 4096 drives x 9000 samples")

    # the derivatives agree with each other (same loss, same point)
    v_rev, g_rev = variants[2][1](z)
    v_fwd, g_fwd, _, _ = variants[3][1](z)
    rel = float(jnp.max(jnp.abs(g_fwd - g_rev)) / jnp.max(jnp.abs(g_rev)))
    print(f"gradient agreement forward-mode vs reverse: max rel diff {rel:.2e}; value diff {float(v_fwd - v_rev):.2e}")
    used = results["forward-mode value+grad+GN Hessian"][1] / base
    print(f"identify uses forward mode for <= 24 coordinates: value_and_grad = {used:.2f}x the forward pass "
          f"(target <= 8x); plain reverse {results['reverse value_and_grad'][1] / base:.2f}x, "
          f"reverse + checkpoint {results['reverse + jax.checkpoint per step'][1] / base:.2f}x")


if __name__ == "__main__":
    main()
