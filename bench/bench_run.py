"""Throughput of jit(vmap(run)) over 64 drives x 36,000 samples (1 h at 10 Hz), float64,
with its compile time, side by side with the slow literal reference loop (tests/oracle.py).

    .venv/bin/python bench/bench_run.py [--drives 64] [--samples 36000] [--mode complementary]

Target (issue 2): >= 1e7 samples/s on a 2-core machine.
"""

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import jaxmodel as jm  # noqa: E402
from drives import city_blocks, seed_model_drive  # noqa: E402
from oracle import run_reference  # noqa: E402


def make_batch(n_drives, n_samples):
    pd = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(n_blocks=400, block=150.0), pd, compass_noise_deg=2.0, seed=0)
    reps = int(np.ceil(n_samples / len(d["time_s"])))
    if reps > 1:  # extend by repeating the route (counters and time continue)
        n0 = len(d["time_s"])
        for key in ("time_s", "left_pulses", "right_pulses"):
            base = d[key]
            step = base[-1] - base[0] + (base[1] - base[0])
            d[key] = np.concatenate([base + k * step for k in range(reps)])
        for key in ("compass_x", "compass_y"):
            d[key] = np.tile(d[key], reps)
        assert len(d["time_s"]) == n0 * reps
    one = {k: v[:n_samples] for k, v in d.items()}
    rng = np.random.default_rng(1)
    cx = one["compass_x"][None, :] + 0.3 * rng.standard_normal((n_drives, n_samples))
    cy = one["compass_y"][None, :] + 0.3 * rng.standard_normal((n_drives, n_samples))
    tile = lambda v: np.broadcast_to(v, (n_drives, n_samples))  # noqa: E731
    return jm.make_inputs(tile(one["time_s"]), tile(one["left_pulses"]), tile(one["right_pulses"]), cx, cy), one, pd


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--drives", type=int, default=64)
    ap.add_argument("--samples", type=int, default=36000)
    ap.add_argument("--mode", default="complementary")
    ap.add_argument("--reference-samples", type=int, default=36000)
    args = ap.parse_args()

    batch, one, pd = make_batch(args.drives, args.samples)
    params = jm.make_params()
    config = jm.Config(mode=args.mode)
    fn = jax.jit(jax.vmap(lambda i: jm.run_from(params, jm.init_state(params), i, config)[1].heading))

    t0 = time.perf_counter()
    compiled = fn.lower(batch).compile()
    compile_s = time.perf_counter() - t0
    compiled(batch).block_until_ready()  # warm
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        compiled(batch).block_until_ready()
        runs.append(time.perf_counter() - t0)
    best = min(runs)
    total = args.drives * args.samples
    jax_rate = total / best

    n_ref = min(args.reference_samples, args.samples)
    t0 = time.perf_counter()
    run_reference(pd, one["time_s"][:n_ref], one["left_pulses"][:n_ref], one["right_pulses"][:n_ref],
                  one["compass_x"][:n_ref], one["compass_y"][:n_ref])
    ref_s = time.perf_counter() - t0
    ref_rate = n_ref / ref_s

    print(f"jit(vmap(run)) {args.mode}, float64, {args.drives} drives x {args.samples} samples = {total:,} samples")
    print(f"  compile time              : {compile_s:8.2f} s")
    print(f"  run time (best of 3)      : {best:8.3f} s   (all: {', '.join(f'{r:.3f}' for r in runs)})")
    print(f"  throughput                : {jax_rate:10.3e} samples/s   (target >= 1e7)")
    print(f"slow reference loop (tests/oracle.py, pure Python), {n_ref:,} samples")
    print(f"  throughput                : {ref_rate:10.3e} samples/s")
    print(f"ratio jax / reference       : {jax_rate / ref_rate:8.1f}x")
    print(f"devices: {jax.devices()}  x64: {jax.config.jax_enable_x64}")


if __name__ == "__main__":
    main()
