"""Start-up of the command line with and without its compilation cache (identification/compile_cache.py).

Simulates one drive, then runs ``odocompass estimate`` on it in fresh processes, side by side:
with the cache off, with an empty cache (which it fills), and again with the cache the previous run
filled; each in every mode asked for.  Prints wall seconds per run, the warm/cold ratio and the
cache's size.

    .venv/bin/python bench/bench_compile_cache.py [--duration 900] [--modes complementary,kalman] [--repeat 2]
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _odocompass():
    exe = Path(sys.executable).parent / "odocompass"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "identification.cli"]


def _run(args, cache, cwd):
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["ODOCOMPASS_CACHE_DIR"] = cache
    t0 = time.perf_counter()
    proc = subprocess.run(_odocompass() + ["-q"] + args, cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"bench_compile_cache: {' '.join(args[:2])} failed: {proc.stderr.strip()}")
    return seconds


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=900.0, help="seconds of driving")
    parser.add_argument("--modes", default="complementary,kalman")
    parser.add_argument("--repeat", type=int, default=2, help="rounds of (off, cold, warm)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-compile-cache-") as tmp:
        tmp = Path(tmp)
        drive = tmp / "drive.parquet"
        _run(["simulate", "--scenario", "urban", "--duration", str(args.duration), "--seed", "1", "--out", str(drive)],
             "off", tmp)
        print(f"odocompass estimate on a {args.duration:.0f}-s urban drive, fresh process each (wall s)")
        print(f"{'mode':14s} {'round':>5s} {'cache off':>10s} {'empty':>8s} {'warm':>8s} {'warm/off':>9s} {'cache MB':>9s}")
        for mode in args.modes.split(","):
            for k in range(args.repeat):
                cache = tmp / f"cache-{mode}-{k}"
                est = ["estimate", str(drive), "--mode", mode, "--out", str(tmp / "est.csv")]
                off = _run(est, "off", tmp)
                cold = _run(est, str(cache), tmp)
                warm = _run(est, str(cache), tmp)
                size = sum(p.stat().st_size for p in cache.iterdir()) / 1e6
                print(f"{mode:14s} {k:5d} {off:10.1f} {cold:8.1f} {warm:8.1f} {warm / off:9.2f} {size:9.1f}")


if __name__ == "__main__":
    main()
