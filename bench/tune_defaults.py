"""Fit the default filter constants by gradient descent on the TUNING seeds of the scenario matrix.

The reason the estimator is in JAX: the constants of the robust F-DELTA filter
(jaxmodel/offset_filter.py) and of FIG. 8C/8E are fitted with optax Adam in log space to the
mean over drives of log(heading MSE after the first minute) of the default mode, every drive
with its own (true) vehicle parameters and calibration on.  Only ``scenarios.TUNING_SEEDS`` are
used; ``bench/bench_scenarios.py`` judges the result on ``EVALUATION_SEEDS``.  Prints the start
and fitted values and the loss; paste the fitted values into jaxmodel/params.py by hand (then
they are frozen).

    .venv/bin/python bench/tune_defaults.py [--iterations 60] [--duration 600] [--seeds 101,102,103] [--start FIT.json]
        [--keys filter_field_sigma,filter_tilt_sigma_deg]
"""

import argparse
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import jaxmodel as jm  # noqa: E402
from jaxmodel.angles import wrap  # noqa: E402
from identification import scenario_eval as ev  # noqa: E402
from identification import scenarios as sc  # noqa: E402

TUNED = ("filter_steady_turn_sigma", "filter_rate_significance", "filter_reject_harden_m",
         "filter_offset_psd", "filter_rate_psd", "filter_rate_sigma0", "filter_check_m", "filter_check_sigma_deg",
         "filter_gate_sigma", "filter_compass_sigma_deg", "filter_compass_corr_m", "filter_ec_weight",
         "filter_turn_sigma", "filter_sigma0_deg", "filter_gm_m", "filter_gm_sigma_deg", "filter_tilt_sigma_deg",
         "filter_tilt_m", "filter_field_sigma")
"""Only constants of the default mode's filter: the kf_* keys of the Kalman mode stay as bench/tune_kalman.py fitted them."""
CONDITIONS = tuple(c for c in sc.CONDITIONS if c not in sc.NO_COMPASS_CONDITIONS and c != "mismatch_0")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=60)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seeds", default=",".join(str(s) for s in sc.TUNING_SEEDS))
    ap.add_argument("--learning-rate", type=float, default=0.08)
    ap.add_argument("--start", help="JSON file of filter constants to start from (default: jaxmodel/params.py)")
    ap.add_argument("--keys", help="comma-separated subset of the constants to fit (default: all of TUNED)")
    args = ap.parse_args()
    keys = args.keys.split(",") if args.keys else list(TUNED)
    unknown = sorted(set(keys) - set(TUNED))
    if unknown:
        ap.error(f"--keys: not a fitted constant: {', '.join(unknown)} (known: {', '.join(TUNED)})")
    seeds = [int(s) for s in args.seeds.split(",")]
    assert not set(seeds) & set(sc.EVALUATION_SEEDS), "never tune on the evaluation seeds"

    t0 = time.perf_counter()
    drives = list(sc.matrix(seeds, conditions=CONDITIONS, duration_s=args.duration))
    # The project's own simulator too (its anomalies, map and vehicle), on seeds no test uses.
    drives += [sc.project_drive(scenario, 300 + seed, args.duration) for seed in seeds
               for scenario in ("urban", "mixed", "highway", "parking")]
    start = json.loads(Path(args.start).read_text()) if args.start else {}
    params = ev.stack_params([d.params for d in drives], start)
    _, inputs, mask, truth, time_s = ev.stacked_inputs(drives)
    keep = jnp.asarray((mask > 0.5) & (time_s - time_s[:, :1] >= ev.SKIP_S), jnp.float64)
    truth = jnp.asarray(truth)
    print(f"{len(drives)} tuning drives (seeds {seeds}), {int(mask.sum())} samples, built in "
          f"{time.perf_counter() - t0:.1f} s")

    theta0 = {k: jnp.log(getattr(params, k)[0]) for k in keys}

    def loss(theta):
        p = params._replace(**{k: jnp.broadcast_to(jnp.exp(v), getattr(params, k).shape) for k, v in theta.items()})
        out = jax.vmap(lambda pp, inp: jm.run_from(pp, jm.init_state(pp), inp, jm.Config(robust=True))[1])(p, inputs)
        err = wrap(out.heading - truth)
        mse = jnp.sum(keep * err ** 2, axis=1) / jnp.sum(keep, axis=1)
        return jnp.mean(jnp.log(mse + 1e-8))

    value_and_grad = jax.jit(jax.value_and_grad(loss))
    opt = optax.adam(args.learning_rate)
    state = opt.init(theta0)
    theta = theta0
    best = (np.inf, theta0)
    for it in range(args.iterations):
        t1 = time.perf_counter()
        value, grad = value_and_grad(theta)
        value = float(value)
        if value < best[0]:
            best = (value, theta)
        grad = jax.tree_util.tree_map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
        updates, state = opt.update(grad, state)
        theta = optax.apply_updates(theta, updates)
        print(f"iter {it:3d} loss {value:.4f} (rms {np.degrees(np.exp(0.5 * value)):.3f} deg geometric) "
              f"{time.perf_counter() - t1:.1f} s", flush=True)
    print(f"\nbest loss {best[0]:.4f} (start {float(loss(theta0)):.4f})")
    print("key, start, fitted:")
    for k in keys:
        print(f"  {k:26s} {float(np.exp(theta0[k])):.4g} -> {float(np.exp(best[1][k])):.4g}")


if __name__ == "__main__":
    main()
