"""Issue 3 Kalman bar over many drives: 15-minute urban drives with 1 Hz fixes (sigma 4 m per axis).

For each seed: the Kalman mode's heading RMSE against the complementary mode's, and its position
RMSE against dead reckoning's (the better of the complementary and odometer-only positions,
both started at the true start point), RMSE after the first minute.  The bar per drive:
heading no worse, position at most half.

    .venv/bin/python bench/bench_kalman_bar.py [--seeds 1-32] [--fixes-model gnss|white|both]

Fix errors (``identification.simulate``, ``--fixes-model``):
* gnss: the simulator's default, half of the variance white and half correlated over 30 s, as a
  real receiver's (multipath, atmosphere);
* white: independent Gaussian errors, the assumption of US 4,680,715 claim 1.
On white fixes two parameter sets run: the shipped defaults (fitted on both kinds of fixes,
bench/tune_kalman.py) and the defaults told the receiver's error (kf_fix_sigma_m = 4,
kf_fix_gm_sigma_m = 0), as a parameter file for such a receiver would.

Also printed per drive: the position RMSE of the best causal average of the fixes given perfect
dead reckoning and an unknown start (a Kalman filter of the start offset with the fixes' exact
error model).  It shows how much of the Kalman mode's position error the fixes alone impose.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import jaxmodel as jm  # noqa: E402
from identification.demo import heading_rmse_deg  # noqa: E402
from identification.drive_log import drive_from_columns  # noqa: E402
from identification.simulate import FIX_CORRELATION_S, FIX_MODELS, simulate  # noqa: E402

SIGMA_M = 4.0
DURATION_S = 900.0
SKIP_S = 60.0
RECEIVER_PARAMS = dict(kf_fix_sigma_m=SIGMA_M, kf_fix_gm_sigma_m=0.0)


def _seeds(text):
    lo, _, hi = text.partition("-")
    return range(int(lo), int(hi or lo) + 1)


def _rmse(out, truth):
    """(heading RMSE deg, position RMSE m) after the first minute."""
    t = truth["time_s"]
    m = t - t[0] >= SKIP_S  # the samples heading_rmse_deg keeps
    d2 = (np.asarray(out.x) - truth["x_m"]) ** 2 + (np.asarray(out.y) - truth["y_m"]) ** 2
    return heading_rmse_deg(out.heading, truth["heading_rad"], t, SKIP_S), math.sqrt(np.mean(d2[m]))


def fix_average_floor(columns, truth, correlated):
    """Position RMSE (m) after the first minute of a causal Kalman estimate of the start offset
    from the fixes alone, dead reckoning perfect: states [offset, correlated fix error] per axis,
    with the simulator's fix error model, whose correlated part starts at 0 one second before the
    first fix (``simulate._fixes``)."""
    valid = np.asarray(columns["fix_valid"]) > 0
    t = truth["time_s"]
    white = SIGMA_M / math.sqrt(2.0) if correlated else SIGMA_M
    colored = SIGMA_M / math.sqrt(2.0) if correlated else 0.0
    h = np.array([1.0, 1.0])
    sq = np.zeros(t.size)
    for key, true in (("fix_east_m", truth["x_m"]), ("fix_north_m", truth["y_m"])):
        y = np.asarray(columns[key]) - true
        first = t[np.argmax(valid)] if valid.any() else t[0]
        x, cov, last, est = np.zeros(2), np.diag([100.0**2, 0.0]), first - 1.0, np.zeros(t.size)
        for k in range(t.size):
            if valid[k]:
                f = math.exp(-(t[k] - last) / FIX_CORRELATION_S)
                last = t[k]
                x = np.array([x[0], f * x[1]])
                cov = np.array([[cov[0, 0], f * cov[0, 1]],
                                [f * cov[0, 1], f * f * cov[1, 1] + colored**2 * (1.0 - f * f)]])
                gain = cov @ h / (h @ cov @ h + white**2)
                x = x + gain * (y[k] - h @ x)
                cov = cov - np.outer(gain, h @ cov)
            est[k] = x[0]
        sq += est**2
    m = t >= t[0] + SKIP_S
    return math.sqrt(np.mean(sq[m]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-32", help="seed range, e.g. 1-32 (default) or 7")
    ap.add_argument("--fixes-model", choices=FIX_MODELS + ("both",), default="both")
    args = ap.parse_args()
    models = FIX_MODELS if args.fixes_model == "both" else (args.fixes_model,)
    run = jax.jit(jm.run, static_argnums=2)
    defaults, receiver = jm.make_params(), jm.make_params(**RECEIVER_PARAMS)
    t0 = time.perf_counter()
    for model in models:
        filters = [("defaults", defaults)] + ([("receiver sigma", receiver)] if model == "white" else [])
        print(f"\n== fixes: {model}, sigma {SIGMA_M} m per axis; urban, {DURATION_S / 60:.0f} min, "
              f"RMSE after {SKIP_S:.0f} s ==")
        head = f"{'seed':>4} {'comp deg':>8} {'DR m':>6} {'floor m':>7}"
        for name, _ in filters:
            head += f" | {name + ': Kalman deg':>22} {'m':>5} {'ratio':>5} {'bar':>4}"
        print(head)
        passed = {name: [] for name, _ in filters}
        for seed in _seeds(args.seeds):
            columns, truth = simulate("urban", DURATION_S, seed, fixes_sigma=SIGMA_M, fixes_model=model)
            drive = drive_from_columns(columns, source=f"urban-{seed}")
            inputs = jm.Inputs(*(jnp.asarray(np.asarray(v, np.float64)) for v in drive.inputs))
            comp_h, comp_pos = _rmse(run(defaults, inputs, jm.Config()), truth)
            _, odo_pos = _rmse(run(defaults, inputs, jm.Config(mode="odometer")), truth)
            dr = min(comp_pos, odo_pos)
            line = f"{seed:>4} {comp_h:>8.3f} {dr:>6.2f} {fix_average_floor(columns, truth, model == 'gnss'):>7.2f}"
            for name, p in filters:
                kal_h, kal_pos = _rmse(run(p, inputs, jm.Config(mode="kalman")), truth)
                ok = kal_h <= comp_h and kal_pos <= 0.5 * dr
                passed[name].append(ok)
                line += f" | {kal_h:>22.3f} {kal_pos:>5.2f} {kal_pos / dr:>5.2f} {'ok' if ok else 'MISS':>4}"
            print(line, flush=True)
        for name, oks in passed.items():
            misses = [s for s, ok in zip(_seeds(args.seeds), oks) if not ok]
            print(f"{model} fixes, {name}: bar met on {sum(oks)} of {len(oks)} drives"
                  + (f"; missed on seeds {', '.join(map(str, misses))}" if misses else ""))
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
