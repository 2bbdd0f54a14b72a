"""Issue 10's scenario matrix: every mode on every drive, the bars, tuning and evaluation seeds.

For each seed set (tuning: the seeds bench/tune_defaults.py fits on; evaluation: never used for
fitting) and each (scenario, condition) of identification.scenarios, prints the heading RMSE
after the first minute of every mode (calibration on; kalman without and with 1 Hz fixes of
sigma 4 m), the ratio of the default mode to the better of odometer-only and compass-only, the
rank correlation of heading_bound with the actual error (positive: honest reliability), and
whether the drive meets the bar.  Then the glitch bar (RMSE from the first glitch to the end
against the same drive without glitches, every mode) and the calibration bar (40-minute mixed
drives, final dpp_ratio against the truth).

    .venv/bin/python bench/bench_scenarios.py [--duration 900] [--tuning 101] [--evaluation 201,202,203]
"""

import argparse
import time

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

from identification import scenario_eval as ev  # noqa: E402
from identification import scenarios as sc  # noqa: E402

MODES = tuple(ev.MODE_CONFIGS)


def table(rows, title):
    print(f"\n## {title}\n")
    print("| drive | " + " | ".join(MODES) + " | ratio | rank corr | bar |")
    print("|---" * (len(MODES) + 4) + "|")
    for r in rows:
        bar = "n/a" if not r["has_compass"] else ("met" if ev.meets_bar(r) else "**MISS**")
        print(f"| {r['name']} | " + " | ".join(f"{r['rmse'][m]:.2f}" for m in MODES)
              + f" | {r.get('ratio', float('nan')):.2f} | {r['bound_error_rank_corr']:.2f} | {bar} |")
    with_compass = [r for r in rows if r["has_compass"]]
    met = sum(ev.meets_bar(r) for r in with_compass)
    print(f"\nbar met on {met} of {len(with_compass)} drives with a compass; "
          f"median ratio {np.median([r['ratio'] for r in with_compass]):.2f}; "
          f"median rank corr {np.nanmedian([r['bound_error_rank_corr'] for r in rows]):.2f}")
    print("median rank corr of heading_bound with the error, per mode: "
          + ", ".join(f"{m} {np.nanmedian([r['rank_corr'][m] for r in rows]):.2f}" for m in MODES))
    return met, len(with_compass)


def glitch_bar(rows):
    print("\n## glitch bar (RMSE from the first glitch to the end, minus the same drive with its counters"
          " restored, deg)\n")
    ok_all = True
    for r in rows:
        if r["condition"] != "glitches" or not r["glitch_rmse"] or "glitch_rmse_ref" not in r:
            continue
        diffs = {m: r["glitch_rmse"][m] - r["glitch_rmse_ref"][m] for m in MODES}
        # Every mode of the default estimator; the seed filter (robust=False) is shown for comparison only.
        ok = all(abs(v) <= 0.1 for m, v in diffs.items() if m != "seed_filter")
        ok_all &= ok
        print(f"{r['name']:28s} " + " ".join(f"{m} {v:+.3f}" for m, v in diffs.items()) + ("  met" if ok else "  MISS"))
    return ok_all


def with_glitch_reference(drives, rows):
    """For each glitched drive, the RMSE of every mode from its first glitch on the same drive
    with the counters restored (same compass noise: the difference is the glitches' alone)."""
    glitched = [d for d in drives if d.condition == "glitches" and d.glitch_time_s is not None]
    restored = ev.evaluate([sc.without_glitches(d) for d in glitched])
    ref = {d.name: r for d, r in zip(glitched, restored)}
    for r in rows:
        if r["name"] in ref:
            r["glitch_rmse_ref"] = ref[r["name"]]["glitch_rmse"]


def calibration_bar(seed, duration):
    print(f"\n## calibration bar ({duration / 60:.0f}-minute mixed drives, seed {seed})\n")
    drives = [sc.make_drive("mixed", f"mismatch_{m:g}", seed, duration_s=duration) for m in (0.0, 0.5, 1.5, 2.5)]
    ok_all = True
    for r in ev.evaluate(drives, modes=("default",)):
        err = r["dpp_ratio"] - r["true_dpp_ratio"]
        limit = 1e-5 if r["true_dpp_ratio"] == 1.0 else 2e-4
        ok = abs(err) <= limit
        ok_all &= ok
        print(f"{r['name']:28s} final dpp_ratio {r['dpp_ratio']:.6f} true {r['true_dpp_ratio']:.6f} "
              f"error {err:+.2e} (bar {limit:.0e}) {'met' if ok else 'MISS'}; default {r['rmse']['default']:.2f} deg")
    return ok_all


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--tuning", default=str(sc.TUNING_SEEDS[0]))
    ap.add_argument("--evaluation", default=",".join(str(s) for s in sc.EVALUATION_SEEDS))
    ap.add_argument("--calibration-duration", type=float, default=2400.0)
    args = ap.parse_args()
    summary = {}
    for title, seeds in (("tuning seeds", args.tuning), ("evaluation seeds", args.evaluation)):
        t0 = time.perf_counter()
        drives = list(sc.matrix([int(s) for s in seeds.split(",")], duration_s=args.duration))
        rows = ev.evaluate(drives)
        with_glitch_reference(drives, rows)
        summary[title] = table(rows, f"{title} {seeds} ({time.perf_counter() - t0:.0f} s)")
        summary[title + " glitch"] = glitch_bar(rows)
    summary["calibration"] = calibration_bar(sc.EVALUATION_SEEDS[0], args.calibration_duration)
    print("\n## summary\n")
    for k, v in summary.items():
        print(f"{k}: {v}")


if __name__ == "__main__":
    main()
