"""Fit the Kalman mode's noise parameters (kf_*) by gradient descent on simulated drives.

This is how the kf_* defaults of jaxmodel/params.py were chosen (docs/calibration-kalman.md):
the filter is differentiable, so its noise parameters are fitted like vehicle parameters,
in log space with optax Adam, against the simulator's true heading and position.

    .venv/bin/python bench/tune_kalman.py [--iterations 100] [--set kf_fix_gm_sigma_m=1e-6 ...]
                                          [--freeze kf_fix_gm_sigma_m,...]

Training drives (15 minutes each): urban seeds 101-104, mixed 105 and highway 106 with 1 Hz
fixes of sigma 4 m whose error is correlated as a receiver's (``fixes_model="gnss"``, the
simulator's default); urban 109-110, mixed 111 and highway 112 with white fixes of the same sigma
(``"white"``, the seed's model), so that the defaults suit both kinds of receiver; urban 107 and
mixed 108 without fixes, so that the compass-only case stays good.  None of them is a bar drive
(bench/bench_kalman_bar.py uses urban seeds 1-32).  Loss, over the samples
after the first minute: mean squared wrapped heading error / (0.5 deg)^2 + mean squared
position error / (2.5 m)^2 (drives with fixes only).  Prints the loss per iteration and the
fitted values as JSON.

kf_gm_m (dth1's correlation distance) is not fitted here and kf_gm_sigma_deg was chosen again since: these drives
cannot tell them (the loss 1.2867 with a time-only dth1, 1.2927 at 180 m); the scenario matrix's tuning seeds chose
them (docs/tuning.md, stop 90).  Pass --freeze kf_gm_sigma_deg to keep that choice.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import jaxmodel as jm  # noqa: E402
from identification.drive_log import drive_from_columns  # noqa: E402
from identification.simulate import simulate  # noqa: E402

TUNED = ("kf_gm_tau_s", "kf_gm_sigma_deg", "kf_drift_psd", "kf_drift_per_m", "kf_turn_sigma", "kf_white_sigma_deg",
         "kf_compass_sigma_deg", "kf_compass_corr_m", "kf_fix_sigma_m", "kf_speed_sigma", "kf_pos_psd",
         "kf_fix_gm_sigma_m", "kf_fix_gm_tau_s", "kf_ramp_psd")
TRAIN = [  # (scenario, seed, fixes model or None for no fixes)
    ("urban", 101, "gnss"), ("urban", 102, "gnss"), ("urban", 103, "gnss"), ("urban", 104, "gnss"),
    ("mixed", 105, "gnss"), ("urban", 109, "white"), ("urban", 110, "white"), ("mixed", 111, "white"),
    ("highway", 112, "white"), ("highway", 106, "gnss"), ("urban", 107, None), ("mixed", 108, None)]
FIXES_SIGMA_M = 4.0
DURATION_S = 900.0
SKIP_S = 60.0
HEADING_SCALE = math.radians(0.5)
POSITION_SCALE_M = 2.5


def training_batch():
    """The training drives as one batch (cut to the shortest), with the truth and masks."""
    inputs, truths = [], []
    for scenario, seed, fixes_model in TRAIN:
        cols, truth = simulate(scenario, DURATION_S, seed, fixes_sigma=FIXES_SIGMA_M if fixes_model else None,
                               fixes_model=fixes_model or "gnss")
        inputs.append([np.asarray(v, np.float64) for v in drive_from_columns(cols, source=f"{scenario}-{seed}").inputs])
        truths.append(truth)
    n = min(i[0].shape[0] for i in inputs)
    batch = jm.Inputs(*(jnp.asarray(np.stack([i[k][:n] for i in inputs])) for k in range(len(jm.Inputs._fields))))
    ref = {k: jnp.asarray(np.stack([t[k][:n] for t in truths])) for k in ("heading_rad", "x_m", "y_m")}
    mask = jnp.asarray(np.stack([t["time_s"][:n] >= t["time_s"][0] + SKIP_S for t in truths]), jnp.float64)
    with_fixes = jnp.asarray([[1.0 if model else 0.0] for _, _, model in TRAIN])
    return batch, ref, mask, with_fixes


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--learning-rate", type=float, default=0.1)
    ap.add_argument("--set", nargs="*", default=[], help="start values KEY=VALUE")
    ap.add_argument("--freeze", default="", help="comma-separated kf_* keys kept at their start value")
    args = ap.parse_args()

    start = jm.make_params(**{k: float(v) for k, v in (s.split("=", 1) for s in args.set)})
    frozen = {k for k in args.freeze.split(",") if k}
    keys = [k for k in TUNED if k not in frozen]
    for k in keys:  # fitted in log space
        if not float(getattr(start, k)) > 0.0:
            raise SystemExit(f"tune_kalman: {k} starts at {float(getattr(start, k))}; a fitted key needs a positive "
                             f"start value (or --freeze {k})")
    batch, ref, mask, with_fixes = training_batch()
    config = jm.Config(mode="kalman")

    def loss(z):
        p = start._replace(**{k: jnp.exp(v) for k, v in z.items()})
        out = jm.run_batch(p, batch, config)
        e_h = jnp.angle(jnp.exp(1j * (out.heading - ref["heading_rad"])))
        heading = jnp.sum(mask * e_h**2) / jnp.sum(mask) / HEADING_SCALE**2
        e_p2 = (out.x - ref["x_m"]) ** 2 + (out.y - ref["y_m"]) ** 2
        position = jnp.sum(with_fixes * mask * e_p2) / jnp.sum(with_fixes * mask) / POSITION_SCALE_M**2
        return heading + position, (heading, position)

    value_and_grad = jax.jit(jax.value_and_grad(loss, has_aux=True))
    z = {k: jnp.log(jnp.asarray(getattr(start, k))) for k in keys}
    opt = optax.adam(args.learning_rate)
    opt_state = opt.init(z)
    t0 = time.perf_counter()
    for it in range(args.iterations + 1):
        (value, (heading, position)), grad = value_and_grad(z)
        print(f"{it:4d} loss {float(value):.4f}  heading RMSE {math.degrees(math.sqrt(float(heading)) * HEADING_SCALE):.3f} deg"
              f"  position RMSE {math.sqrt(float(position)) * POSITION_SCALE_M:.3f} m  {time.perf_counter() - t0:.0f} s",
              flush=True)
        if it == args.iterations:  # the printed loss is that of the values written below
            break
        updates, opt_state = opt.update(grad, opt_state)
        z = optax.apply_updates(z, updates)
    print(json.dumps({k: float(jnp.exp(v)) for k, v in z.items()}))


if __name__ == "__main__":
    main()
