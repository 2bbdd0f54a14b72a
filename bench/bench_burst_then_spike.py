"""A spike soon after a burst: does the spike change what the burst leaves?

The guard (jaxmodel/plausibility.py) removes a burst of spurious pulses as a rounded whole number, and the vernier
(jaxmodel/vernier.py) estimates that removal again VERNIER_SAMPLES samples later.  A +3000-count spike's first
sample is a rounded removal too, and its return an exact one.  Until stop 88 the spike's estimate replaced the
burst's and its return cancelled it, so a spike within the burst's window decided the burst's outcome.  This bench
puts a 20-pulse burst on the left wheel of a ``baseline`` drive at random moving samples, alone and with a one-sample
+3000 spike on the same wheel 3 and 6 samples later, and prints the odometer mode's final wheel heading less the
clean drive's (deg), then how often the spike changed the outcome by more than 0.1 deg and how often the glitched
drive ended more than 0.1 deg off.

    .venv/bin/python bench/bench_burst_then_spike.py urban:117 highway:118 mixed:119 [--bursts 20]

mixed:101 (rng 7) was looked at while building the shadow slot; 117-119 judged it once.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from identification import scenarios as sc  # noqa: E402
from identification.drive_log import wrap_rad  # noqa: E402
from matrix_drives import run_drive  # noqa: E402

BURST_PULSES = 20
SPIKE_COUNTS = 3000
SPIKE_AFTER = (3, 6)  # samples from the burst to the spike


def _end_heading(drive):
    return float(run_drive(drive, mode="odometer", robust=True).wheel_heading[-1])


def _glitched(base, at, spike_after=None):
    drive = copy.deepcopy(base)
    left = sc.unwrap_counter(drive.columns["left_pulses"])
    left[at:] += BURST_PULSES
    if spike_after is not None:
        left[at + spike_after] += SPIKE_COUNTS
    drive.columns["left_pulses"] = left % 65536
    return drive


def _bench(scenario, seed, bursts, rng_seed):
    base = sc.make_drive(scenario, "baseline", seed)
    speed = np.asarray(base.truth["speed_mps"])
    moving = np.flatnonzero(speed > 3.0)
    moving = moving[(moving > 600) & (moving < speed.size - 50)]
    picks = np.sort(np.random.default_rng(rng_seed).choice(moving, size=bursts, replace=False))
    clean = _end_heading(base)
    rows = []
    for at in picks:
        ends = [_end_heading(_glitched(base, at, s)) for s in (None, *SPIKE_AFTER)]
        rows.append(np.degrees(wrap_rad(np.asarray(ends) - clean)))
        print(f"{scenario}/{seed} burst at {at}: alone {rows[-1][0]:+.3f}, "
              + ", ".join(f"spike +{s} {v:+.3f}" for s, v in zip(SPIKE_AFTER, rows[-1][1:])), flush=True)
    return np.asarray(rows)


def _summary(label, rows):
    """How often the spike changed the outcome by more than 0.1 deg, and how often a drive ended more than 0.1 deg
    off, alone and with a spike.  rows: (bursts, 1 + len(SPIKE_AFTER)) of ``_bench``."""
    changed = np.abs(rows[:, 1:] - rows[:, :1]) > 0.1
    print(f"{label}: the spike changed the outcome in {changed.sum()} of {changed.size}; ended > 0.1 deg off: "
          f"alone {np.sum(np.abs(rows[:, 0]) > 0.1)} of {len(rows)}, with a spike "
          f"{np.sum(np.abs(rows[:, 1:]) > 0.1)} of {changed.size}", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("drives", nargs="+", help="scenario:seed of baseline drives")
    ap.add_argument("--bursts", type=int, default=20)
    ap.add_argument("--rng", type=int, default=7, help="seed of the burst positions")
    args = ap.parse_args()
    total = []
    for item in args.drives:
        scenario, seed = item.split(":")
        total.append(_bench(scenario, int(seed), args.bursts, args.rng))
        _summary(item, total[-1])
    _summary("all", np.concatenate(total))


if __name__ == "__main__":
    main()
