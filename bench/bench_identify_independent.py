"""``odocompass identify`` on the independent simulator's vehicles: a calibration engineer's workflow, end to end.

For each vehicle seed V the independent simulator (bench/independent_sim.py, ``vehicle_seed``) draws one vehicle and
drives it on several routes: training drives (default urban, mixed, urban_hilly, 15 minutes each) and held-out drives
(default urban, mixed).  The engineer's starting file is a datasheet: the sensor axle, the counters' modulus and the
compass's factory calibration as the simulator writes them, the tracks 2 % short and the wheel base 3 % long, P 0.15,
a 0 (never measured) and both wheels' distance per pulse from a nominal tyre 1 % off their mean (no mismatch known).
It runs

    odocompass identify TRAIN... --params start.json --out fitted.json --fit KEYS --validate HELD...

with KEYS the sensor axle's geometry, a and dpp_right (``--fit``: P,B,T_F,a,dpp_right for a front sensor axle,
T_R,a,dpp_right for a rear one, each with identify's filter keys T_C,D_N), then scores the held-out drives' heading
RMSE (deg, after the first 60 s) with the start file, the fitted file and the true vehicle (the start file with the
simulator's own P, B, T_F, T_R, a, dpp), in the odometer mode and the default mode.  Printed per vehicle: the fitted
values against the truth (the turn's scale T/dpp, which a heading alone identifies; the ratio dpp_right/dpp_left in
ppm; a), and the RMSE table with the ratio fitted/true (issue 4's bar: within 10 % in the odometer mode).

    python bench/bench_identify_independent.py [VEHICLE ...] [--train urban,mixed,urban_hilly] [--held urban,mixed]
        [--duration 900] [--work-dir /tmp/indep/identify]

Vehicle seeds 1-3 were looked at while writing this bench (stop 89); 4 and 5 judged once, and 5 found a defect
(identify's tyre start, docs/benchmarks.md), so it is a diagnosis vehicle since; 6 and above judge.  Route seeds are
1000 + 10 V + i (training i = 0, 1, ...; held out i = 5, 6, ...), drives no other bench uses.  Never choose a constant
on these drives (bench_independent.py's rule).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

sys.dont_write_bytecode = True          # leave no __pycache__ in bench/
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, ROOT)
import independent_sim as sim  # noqa: E402
import jax  # noqa: E402
from bench_independent import SKIP_S, find_cli  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import jaxmodel as jm  # noqa: E402
from bench._common import rmse_deg  # noqa: E402
from identification.drive_log import read_drive  # noqa: E402
from identification.estimate import estimate_drive  # noqa: E402

VEHICLE_KEYS = ("P", "B", "T_F", "T_R", "a", "dpp_left", "dpp_right")
FILTER_KEYS = ("T_C", "D_N")


def datasheet(true):
    """The engineer's starting file from the simulator's true one (see the module doc)."""
    dpp = 0.5 * (true["dpp_left"] + true["dpp_right"]) * 1.01
    return dict(true, P=0.15, B=true["B"] * 1.03, T_F=true["T_F"] * 0.98, T_R=true["T_R"] * 0.98, a=0.0,
                dpp_left=dpp, dpp_right=dpp)


def fit_keys(true):
    geometry = ("P", "B", "T_F") if true["sensor_axle"] == "front" else ("T_R",)
    return (*geometry, "a", "dpp_right", *FILTER_KEYS)


def rmse_after(cols, drive):
    keep = np.asarray(drive.inputs.time_s) >= SKIP_S
    return rmse_deg(np.asarray(cols["heading_deg"])[keep], np.asarray(drive.ref_heading)[keep])


def one_vehicle(v, train_kinds, held_kinds, duration, work):
    train, held = [], []
    for i, kind in enumerate(train_kinds):
        train.append(sim.make_drive(kind, 1000 + 10 * v + i, work, duration=duration, vehicle_seed=v))
    for i, kind in enumerate(held_kinds):
        held.append(sim.make_drive(kind, 1000 + 10 * v + 5 + i, work, duration=duration, vehicle_seed=v))
    with open(train[0][1]) as f:
        true = json.load(f)
    start = datasheet(true)
    keys = fit_keys(true)
    start_path = os.path.join(work, f"v{v}.start.json")
    out_path = os.path.join(work, f"v{v}.fitted.json")
    with open(start_path, "w") as f:
        json.dump(start, f, indent=1)
    cmd = [find_cli(), "identify", "-q", *[c for c, _ in train], "--params", start_path, "--out", out_path,
           "--fit", ",".join(keys), "--validate", *[c for c, _ in held]]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        print(proc.stderr.strip())
        return None
    with open(out_path) as f:
        fitted = json.load(f)
    report = fitted.pop("report")
    axle_t = "T_F" if true["sensor_axle"] == "front" else "T_R"
    print(f"vehicle {v}: {true['sensor_axle']} sensor axle, {100 * true['dpp_left']:.2f}-cm pulses, "
          f"tyres {1e6 * (true['dpp_right'] / true['dpp_left'] - 1):+.0f} ppm; identify on "
          f"{len(train)} x {duration / 60:.0f} min ({', '.join(train_kinds)}) in {wall:.0f} s, "
          f"{report.get('iterations', '?')} iterations; --fit {','.join(keys)}")
    for w in report.get("warnings", []):
        print(f"  identify warned: {w}")
    scale = lambda p: p[axle_t] / (0.5 * (p["dpp_left"] + p["dpp_right"]))  # noqa: E731
    ratio = lambda p: 1e6 * (p["dpp_right"] / p["dpp_left"] - 1)  # noqa: E731
    print(f"  {'':12s} {'start':>12s} {'fitted':>12s} {'true':>12s}")
    for k in ("P", "B", axle_t, "a"):
        if k in keys:
            print(f"  {k:12s} {start[k]:12.6g} {fitted[k]:12.6g} {true[k]:12.6g}")
    print(f"  {axle_t + '/dpp':12s} {scale(start):12.2f} {scale(fitted):12.2f} {scale(true):12.2f}   "
          f"(fitted/true - 1: {scale(fitted) / scale(true) - 1:+.2%})")
    print(f"  {'ratio, ppm':12s} {ratio(start):12.0f} {ratio(fitted):12.0f} {ratio(true):12.0f}")
    files = {name: jm.make_params(p) for name, p in
             (("start", start), ("fitted", fitted), ("true", dict(start, **{k: true[k] for k in VEHICLE_KEYS})))}
    rows = []
    for (csv_path, _), kind in zip(held, held_kinds):
        drive = read_drive(csv_path)
        for mode in ("odometer", "complementary"):
            r = {name: rmse_after(estimate_drive(params, drive, jm.Config(mode=mode)), drive)
                 for name, params in files.items()}
            rows.append((kind, mode, r))
            print(f"  held-out {kind:12s} {mode:14s} RMSE start {r['start']:6.2f}  fitted {r['fitted']:6.2f}  "
                  f"true {r['true']:6.2f} deg   fitted/true {r['fitted'] / r['true']:5.2f}")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("vehicles", nargs="*", type=int, default=[1])
    ap.add_argument("--train", default="urban,mixed,urban_hilly")
    ap.add_argument("--held", default="urban,mixed")
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--work-dir", default="/tmp/indep/identify")
    a = ap.parse_args(argv)
    os.makedirs(a.work_dir, exist_ok=True)
    ratios = {"odometer": [], "complementary": []}
    for v in a.vehicles:
        rows = one_vehicle(v, a.train.split(","), a.held.split(","), a.duration, a.work_dir)
        for _, mode, r in rows or ():
            ratios[mode].append(r["fitted"] / r["true"])
    for mode, rs in ratios.items():
        if rs:
            print(f"{mode}: held-out RMSE fitted/true median {np.median(rs):.2f}, max {max(rs):.2f}, "
                  f"within 10 %: {sum(x <= 1.10 for x in rs)} of {len(rs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
