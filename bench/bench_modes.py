"""Throughput of the issue-3 additions against the complementary mode alone, side by side.

jit(vmap(run)) over a batch of simulated urban drives with 1 Hz fixes, float64, for
  * complementary, calibration off   (the baseline)
  * complementary, calibration on    (EP 0619873 left/right dpp calibration, the default)
  * kalman, calibration on           (US 4,680,715 Kalman mode)
each compiled once (compile time reported), then the best of --repeats timed runs; the three
configurations are measured in one process, interleaved round by round, so the ratios compare
like with like.

    .venv/bin/python bench/bench_modes.py [--drives 16] [--samples 36000] [--repeats 3]
"""

import argparse
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxmodel as jm  # noqa: E402
from identification.drive_log import drive_from_columns  # noqa: E402
from identification.simulate import simulate  # noqa: E402

CONFIGS = {
    "complementary, calibration off": jm.Config(mode="complementary", calibration=False),
    "complementary, calibration on": jm.Config(mode="complementary", calibration=True),
    "kalman, calibration on": jm.Config(mode="kalman", calibration=True),
}


def make_batch(n_drives, n_samples):
    duration = n_samples * 0.1 + 60.0  # a few dropped samples: simulate a little longer, then cut
    drives = []
    for seed in range(n_drives):
        cols, _ = simulate("urban", duration, 100 + seed, fixes_sigma=4.0, dpp_mismatch=0.003)
        d = drive_from_columns(cols, source=f"bench-{seed}")
        drives.append([np.asarray(v, np.float64)[:n_samples] for v in d.inputs])
    n = min(len(d[0]) for d in drives)
    return jm.Inputs(*(jnp.asarray(np.stack([d[i][:n] for d in drives])) for i in range(len(jm.Inputs._fields))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drives", type=int, default=16)
    ap.add_argument("--samples", type=int, default=36000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    batch = make_batch(args.drives, args.samples)
    n_drives, n_samples = batch.time_s.shape
    total = n_drives * n_samples
    params = jm.make_params()

    compiled, compile_s = {}, {}
    for name, config in CONFIGS.items():
        fn = jax.jit(jax.vmap(lambda inp, config=config: jm.run_from(params, jm.init_state(params), inp, config)[1]))
        t0 = time.perf_counter()
        compiled[name] = fn.lower(batch).compile()
        compile_s[name] = time.perf_counter() - t0
        jax.block_until_ready(compiled[name](batch))  # warm-up
    times = {name: [] for name in CONFIGS}
    for _ in range(args.repeats):  # interleaved rounds
        for name in CONFIGS:
            t0 = time.perf_counter()
            jax.block_until_ready(compiled[name](batch))
            times[name].append(time.perf_counter() - t0)

    base = total / min(times["complementary, calibration off"])
    print(f"jit(vmap(run)), float64, {n_drives} simulated urban drives x {n_samples} samples = {total:,} samples "
          f"(1 Hz fixes, right wheel dpp +0.3 %); best of {args.repeats}")
    print(f"{'configuration':34s} {'compile s':>9s} {'run s':>8s} {'samples/s':>11s} {'vs baseline':>11s}")
    for name in CONFIGS:
        rate = total / min(times[name])
        print(f"{name:34s} {compile_s[name]:9.2f} {min(times[name]):8.3f} {rate:11.3e} {rate / base:10.2f}x")
    print(f"devices: {jax.devices()}  x64: {jax.config.jax_enable_x64}")


if __name__ == "__main__":
    main()
