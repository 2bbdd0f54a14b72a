"""Throughput of jit(vmap(run)) over 64 drives x 36,000 samples (1 h at 10 Hz), float64,
with its compile time, side by side with the slow literal reference loop (tests/oracle.py).

    .venv/bin/python bench/bench_run.py [--drives 64] [--samples 36000] [--devices 2]

Target (issue 2): >= 1e7 samples/s on a 2-core machine.  Each configuration of jaxmodel.Config
is measured: the complementary filter alone (refinement of a and calibration off), with the
refinement of a, and the full default (refinement + left/right calibration).  ``--devices 2``
splits the host into two XLA CPU devices and shards the drive axis over them (one per core).
"""

import os
import sys

if "--devices" in sys.argv:  # must be set before jax is imported
    _n = sys.argv[sys.argv.index("--devices") + 1]
    os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={_n}"

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
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


CONFIGS = {
    "complementary (refine off, calibration off)": dict(mode="complementary", refine_a=False, calibration=False),
    "complementary + refinement of a": dict(mode="complementary", refine_a=True, calibration=False),
    "complementary, full default (+ calibration)": dict(mode="complementary"),
    "seed filter, full (the default before issue 10)": dict(mode="complementary", robust=False),
    "odometer": dict(mode="odometer", refine_a=False, calibration=False),
}


def batch_headings(params, config):
    """The function the throughput is measured on: headings of a batch of drives, vmap(run)."""
    return jax.vmap(lambda i: jm.run_from(params, jm.init_state(params), i, config)[1].heading)


def measure(params, batch, config, sharding=None):
    fn = batch_headings(params, config)
    jitted = jax.jit(fn) if sharding is None else jax.jit(fn, in_shardings=sharding, out_shardings=sharding)
    t0 = time.perf_counter()
    compiled = jitted.lower(batch).compile()
    compile_s = time.perf_counter() - t0
    compiled(batch).block_until_ready()  # warm
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        compiled(batch).block_until_ready()
        runs.append(time.perf_counter() - t0)
    return compile_s, min(runs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--drives", type=int, default=64)
    ap.add_argument("--samples", type=int, default=36000)
    ap.add_argument("--devices", type=int, default=1)
    ap.add_argument("--reference-samples", type=int, default=36000)
    args = ap.parse_args()

    batch, one, pd = make_batch(args.drives, args.samples)
    params = jm.make_params()
    sharding = None
    if args.devices > 1:
        from jax.sharding import Mesh, NamedSharding, PartitionSpec

        sharding = NamedSharding(Mesh(np.array(jax.devices()[: args.devices]), ("drives",)), PartitionSpec("drives"))
        batch = jax.device_put(batch, sharding)
    total = args.drives * args.samples

    n_ref = min(args.reference_samples, args.samples)
    t0 = time.perf_counter()
    run_reference(pd, one["time_s"][:n_ref], one["left_pulses"][:n_ref], one["right_pulses"][:n_ref],
                  one["compass_x"][:n_ref], one["compass_y"][:n_ref])
    ref_rate = n_ref / (time.perf_counter() - t0)

    print(f"jit(vmap(run)), float64, {args.drives} drives x {args.samples} samples = {total:,} samples, "
          f"{args.devices} XLA CPU device(s); {jax.devices()[0].platform}, x64 {jax.config.jax_enable_x64}")
    print(f"slow reference loop (tests/oracle.py, pure Python, complementary without refinement): "
          f"{ref_rate:.3e} samples/s over {n_ref:,} samples")
    print(f"{'configuration':46s} {'compile s':>9s} {'run s':>7s} {'samples/s':>11s} {'vs target 1e7':>13s} {'vs reference':>12s}")
    rates = {}
    for name, kwargs in CONFIGS.items():
        compile_s, best = measure(params, batch, jm.Config(**kwargs), sharding)
        rate = rates[name] = total / best
        print(f"{name:46s} {compile_s:9.2f} {best:7.3f} {rate:11.3e} {rate / 1e7:12.2f}x {rate / ref_rate:11.0f}x",
              flush=True)
    ratio = rates["complementary, full default (+ calibration)"] / rates["seed filter, full (the default before issue 10)"]
    print(f"default (robust) / previous default (seed filter), measured side by side: {ratio:.2f}x (issue 10 bar: >= 0.8x)")


if __name__ == "__main__":
    main()
