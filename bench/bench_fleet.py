"""Issue 13 bars, measured end to end: ``odocompass fleet identify`` on a simulated fleet against a
sequential loop of ``odocompass identify`` over a subset of the same vehicles, side by side.

    .venv/bin/python bench/bench_fleet.py [--vehicles 200] [--minutes 10] [--subset 4] [--workers 2]
                                          [--batch 8] [--fit P,B,T_F,a,T_C,D_N,dpp_right] [--keep DIR]

The fleet: ``--vehicles`` vehicles drawn around one datasheet (the start file: P 0.125, B 2.70 m,
T_F 1.55 m, a 0): T_F +-3 %, B +-2 %, a uniform in 0..6e-4 s²/m², right/left distance-per-pulse
mismatch uniform in +-1 %; each drives a ``--minutes`` mixed and a ``--minutes`` urban drive
(Parquet).  One more vehicle has a corrupt log (it must end ``error``, the others finish).

Both runs are subprocesses, so their wall times include interpreter start-up, imports, Ray's
start (fleet) and every compilation.  The sequential loop is the per-vehicle cost a user pays
today; its time per vehicle, times the fleet size, is compared with the fleet's wall time.
Printed: the fleet's wall time and vehicles per minute, the loop's seconds per vehicle, the
speed-up (bar >= 5x), the fraction of vehicles with T_F within 0.5 % and a within 15 % (bar: 95 %
each), for the fleet and for the loop's subset, and the corrupt vehicle's row.

The fit set includes ``dpp_right``: with a right/left mismatch of up to 1 % the odometer heading
drifts by up to ~2 rad per 30 s at town speeds; fitting without it (or without the calibration)
identifies nothing (the identify loop is run with the same set).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from identification.drive_log import write_drive  # noqa: E402
from identification.simulate import simulate  # noqa: E402

START = dict(P=0.125, B=2.70, T_F=1.55, a=0.0)
ODOCOMPASS = str(ROOT / ".venv" / "bin" / "odocompass")


def make_fleet(work: Path, n: int, minutes: float, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    truth, rows = {}, ["vehicle_id,path,role"]
    for v in range(n):
        vid = f"veh{v:04d}"
        p = dict(START, T_F=START["T_F"] * (1 + rng.uniform(-0.03, 0.03)), B=START["B"] * (1 + rng.uniform(-0.02, 0.02)),
                 a=rng.uniform(0.0, 6e-4))
        mismatch = rng.uniform(-0.01, 0.01)
        for i, sc in enumerate(("mixed", "urban")):
            path = work / "drives" / f"{vid}_{sc}.parquet"
            if not path.exists():
                write_drive(path, simulate(sc, 60.0 * minutes, seed=seed * 100_000 + 10 * v + i, params=p,
                                           dpp_mismatch=mismatch)[0])
            rows.append(f"{vid},drives/{path.name},train")
        truth[vid] = dict(p, dpp_mismatch=mismatch)
    bad = work / "drives" / "corrupt_mixed.parquet"
    bad.write_bytes(b"PAR1" + os.urandom(2048))  # a truncated, corrupt Parquet file
    rows.append(f"corrupt,drives/{bad.name},train")
    (work / "manifest.csv").write_text("\n".join(rows) + "\n")
    # only the datasheet keys (the others take the table defaults): a file that stays valid while
    # jaxmodel's parameter table grows
    (work / "start.json").write_text(json.dumps(START, indent=1) + "\n")
    return truth


def recovered(fitted: dict, true: dict) -> tuple[bool, bool]:
    return abs(fitted["T_F"] / true["T_F"] - 1.0) <= 0.005, abs(fitted["a"] / true["a"] - 1.0) <= 0.15


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=200)
    ap.add_argument("--minutes", type=float, default=10.0, help="length of each of the two drives")
    ap.add_argument("--subset", type=int, default=4, help="vehicles identified one by one by `odocompass identify`")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--fit", default="P,B,T_F,a,T_C,D_N,dpp_right")
    ap.add_argument("--optimizer", default="gauss-newton")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", default=None, help="keep the fleet (drives, outputs) in this folder; reused if present")
    ap.add_argument("--reuse-fleet", action="store_true",
                    help="with --keep: take the fleet run (outputs and wall time) from a previous run in that folder")
    args = ap.parse_args()

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="odocompass-fleet-"))
    (work / "drives").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    truth = make_fleet(work, args.vehicles, args.minutes, args.seed)
    print(f"fleet: {args.vehicles} vehicles x (mixed + urban, {args.minutes:g} min each) + 1 corrupt log, simulated "
          f"in {time.perf_counter() - t0:.0f} s; fit {args.fit}; {os.cpu_count()} CPUs; {work}")

    out = work / "fleet_out"
    cmd = [ODOCOMPASS, "-q", "fleet", "identify", str(work / "manifest.csv"), "--params", str(work / "start.json"),
           "--out", str(out), "--fit", args.fit, "--batch", str(args.batch), "--optimizer", args.optimizer]
    if args.workers:
        cmd += ["--workers", str(args.workers)]
    if args.reuse_fleet and (work / "fleet_wall.json").exists():
        fleet_wall = json.loads((work / "fleet_wall.json").read_text())["wall_s"]
        print(f"fleet identify: reused from {out} ({fleet_wall:.1f} s)")
    else:
        for f in out.glob("*.json") if out.exists() else []:
            f.unlink()  # a fresh run, not a resume
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        fleet_wall = time.perf_counter() - t0
        print(f"fleet identify: exit {proc.returncode} in {fleet_wall:.1f} s")
        if proc.returncode not in (0, 3):
            print(proc.stderr[-3000:])
            raise SystemExit("fleet identify failed")
        (work / "fleet_wall.json").write_text(json.dumps({"wall_s": fleet_wall, "command": cmd}) + "\n")
    import pyarrow.parquet as pq

    rows = {r["vehicle_id"]: r for r in pq.read_table(out / "summary.parquet").to_pylist()}

    seq_times, seq_fit = [], {}
    subset = list(truth)[: args.subset]
    for vid in subset:
        fit_path = work / "identify_out" / f"{vid}.json"
        fit_path.parent.mkdir(exist_ok=True)
        drives = [str(work / "drives" / f"{vid}_{sc}.parquet") for sc in ("mixed", "urban")]
        t0 = time.perf_counter()
        p = subprocess.run([ODOCOMPASS, "-q", "identify", *drives, "--params", str(work / "start.json"), "--out",
                            str(fit_path), "--fit", args.fit], capture_output=True, text=True)
        seq_times.append(time.perf_counter() - t0)
        if p.returncode != 0:
            print(f"identify {vid}: exit {p.returncode}: {p.stderr.strip()[-500:]}")
            continue
        seq_fit[vid] = json.loads(fit_path.read_text())
    seq_per_vehicle = float(np.mean(seq_times))

    n = args.vehicles
    finished = [vid for vid in truth if rows[vid]["status"] in ("ok", "warning")]
    tf_ok = [vid for vid in finished if recovered(rows[vid], truth[vid])[0]]
    a_ok = [vid for vid in finished if recovered(rows[vid], truth[vid])[1]]
    vpm = n / fleet_wall * 60.0
    seq_total = seq_per_vehicle * n
    speedup = seq_total / fleet_wall
    print()
    print(f"{'':44s} {'fleet':>14s} {'identify loop':>14s}")
    print(f"{'vehicles':44s} {n:14d} {len(subset):14d}")
    print(f"{'wall time, s':44s} {fleet_wall:14.1f} {sum(seq_times):14.1f}")
    print(f"{'seconds per vehicle':44s} {fleet_wall / n:14.2f} {seq_per_vehicle:14.2f}")
    print(f"{'vehicles per minute':44s} {vpm:14.2f} {60.0 / seq_per_vehicle:14.2f}")
    sub_tf = [vid for vid in seq_fit if recovered(seq_fit[vid], truth[vid])[0]]
    sub_a = [vid for vid in seq_fit if recovered(seq_fit[vid], truth[vid])[1]]
    print(f"{'T_F within 0.5 % (bar >= 95 %)':44s} {len(tf_ok) / n:14.1%} {len(sub_tf) / max(len(subset), 1):14.1%}")
    print(f"{'a within 15 % (bar >= 95 %)':44s} {len(a_ok) / n:14.1%} {len(sub_a) / max(len(subset), 1):14.1%}")
    print()
    print(f"speed-up: a sequential identify loop over the {n} vehicles would take ~{seq_total:.0f} s "
          f"({seq_per_vehicle:.1f} s x {n}); the fleet took {fleet_wall:.0f} s: {speedup:.1f}x (bar >= 5x)")
    statuses = {s: sum(r["status"] == s for r in rows.values()) for s in ("ok", "warning", "error")}
    print(f"statuses: {statuses}; corrupt vehicle: {rows['corrupt']['status']}: {rows['corrupt']['error']}")
    others_err = [vid for vid in truth if rows[vid]["status"] == "error"]
    print(f"the other {n} vehicles finished: {not others_err}" + (f" (errors: {others_err[:5]})" if others_err else ""))
    agree = [abs(rows[vid]["T_F"] / seq_fit[vid]["T_F"] - 1.0) for vid in seq_fit]
    if agree:
        print(f"fleet vs identify on the subset: max |T_F_fleet / T_F_identify - 1| = {max(agree):.2e}")
    small_a = [vid for vid in finished if vid not in a_ok]
    if small_a:
        print("a outside 15 %: " + ", ".join(f"{vid} (true {truth[vid]['a']:.2e}, fitted {rows[vid]['a']:.2e} "
                                             f"+- {rows[vid]['a_std_error']:.1e})" for vid in small_a[:12]))
    miss_tf = [vid for vid in finished if vid not in tf_ok]
    if miss_tf:
        print("T_F outside 0.5 %: " + ", ".join(f"{vid} ({rows[vid]['T_F'] / truth[vid]['T_F'] - 1:+.2%})"
                                                for vid in miss_tf[:12]))


if __name__ == "__main__":
    main()
