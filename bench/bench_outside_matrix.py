"""Disturbances outside issue 10's matrix: what the default does with faults nobody designed it for.

Each disturbance below is applied to the ``baseline`` drives of the matrix (identification.scenarios, one
drive per scenario and seed), and every drive is run in the default, odometer-only and compass-only modes
(calibration on); the table prints each mode's heading RMSE after the first minute (deg), and the default's
ratio to the better of the other two (the issue-10 bar asks for at most 1.25).  None of these models is used
to choose a constant: the bench only says where the default stands outside the conditions it was tuned on.

==================  ===================================================================================
none                the baseline drive as it is (the reference row)
compass_lag         the compass low-passed with a time constant of 0.7 s (a filtered magnetometer); since stop 29
                    the default's ``filter_compass_lag_s`` answers it (chosen on the matrix, not on this row)
compass_delay       every compass sample logged 0.3 s late (a transport delay; added after that choice, as a judge)
compass_hold        the compass sampled at 2 Hz and held in between (a slower sensor on a 10-Hz log)
compass_spikes      1 % of the compass samples off by a 15-µT (per axis) Gaussian spike
fixed_hard_iron     a constant 3-µT offset from the start that the parameters do not know (uncalibrated)
wheel_slip          the left wheel over-counts by 0.2 % while |acceleration| > 1.5 m/s^2 (a driven wheel)
spurious_pulses     single extra pulses on either wheel at random, 2 per minute (electrical noise)
log_5hz, _2hz, _1hz every sensor logged at 5, 2 or 1 Hz instead of 10 Hz (every 2nd, 5th or 10th sample kept)
time_jitter         the logged time stamps off by up to +-20 ms at random (a logger that is not real-time; the
                    sensors were sampled on time)
dropped_rows        3 % of the rows lost at random and one 3-s gap (a logger that drops samples)
counter_reset       both pulse counters restart from 0 halfway through the drive (an ECU reset)
stuck_wheel         the left counter stops for 5 s at 40 % of the drive, then counts on (the pulses are lost)
stuck_wheel_long    the same for 10 s at 60 % of the drive (stop 32)
coarse_pulses       every third pulse counted (a ring of fewer teeth: 4-9 cm per pulse; the vehicle's dpp x 3)
compass_noise       1 µT more white noise on each compass axis (a cheaper magnetometer: ~3 deg per sample)
weak_field          the compass reads half the field, with the sensor's own 0.25 µT of noise (a high latitude)
counters_held_5     both wheel counters updated every 5th sample and repeated in between (counters sent at 2 Hz, logged
                    at 10 Hz); stop 44
counters_held_10    the same, every 10th sample (1 Hz)
pulse_chatter       the left counter over-counts by 1 pulse per sample for 2 s at half the drive (a chafed cable:
                    20 pulses, each sample within the guard's tolerance; a step of the wheel heading); stop 64
burst_over_5        25 pulses over 5 samples (a burst logged across samples, 5 per sample); stop 64
==================  ===================================================================================

The four from time_jitter on were added at stop 31, after the default's constants were frozen, as judges only.
compass_noise, weak_field and coarse_pulses were added at stop 37; coarse_pulses (seeds 101/104) chose the form of
odometer.INTERVAL_MIN_PULSES, so it judges on other seeds only (107/108: docs/benchmarks.md).  The two counters_held
rows were added at stop 44 and chose the form of ``odometer.COUNTS_HOLD_MAX_S`` (seeds 107/108): they judge on other
seeds only.  pulse_chatter and burst_over_5 (stop 64) chose the form of jaxmodel/wheel_step.py on seeds 101/104: they
judge on other seeds only.

``--axle rear`` draws the same vehicles with their wheel sensors on the rear axle (no Ackerman geometry; stop 32).
``--kalman`` prints the Kalman mode (no fixes) too, beside the ratio and not in it (stop 88: its stuck_wheel and
wheel_slip rows, docs/tuning.md).

    .venv/bin/python bench/bench_outside_matrix.py [--seeds 101,104] [--duration 900] [--only NAME,...] [--axle rear]
                                                   [--kalman]
"""

import argparse
import copy
import time

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

from identification import scenario_eval as ev  # noqa: E402
from identification import scenarios as sc  # noqa: E402

MODES = ("default", "odometer", "compass")


def _compass_lag(drive, tau_s=0.7):
    t = drive.columns["time_s"]
    cx, cy = np.array(drive.columns["compass_x"], float), np.array(drive.columns["compass_y"], float)
    keep = np.exp(-np.diff(t) / tau_s)
    for i in range(1, t.size):
        cx[i] = keep[i - 1] * cx[i - 1] + (1.0 - keep[i - 1]) * cx[i]
        cy[i] = keep[i - 1] * cy[i - 1] + (1.0 - keep[i - 1]) * cy[i]
    drive.columns["compass_x"], drive.columns["compass_y"] = cx, cy


def _compass_delay(drive, delay_s=0.3):
    """Each compass sample logged ``delay_s`` late (a transport delay; the first samples repeat the first)."""
    t = np.asarray(drive.columns["time_s"], float)
    shift = int(round(delay_s / np.median(np.diff(t))))
    for key in ("compass_x", "compass_y"):
        c = np.asarray(drive.columns[key])
        drive.columns[key] = np.concatenate([np.repeat(c[:1], shift), c[:-shift]])


def _compass_hold(drive, every=5):
    for key in ("compass_x", "compass_y"):
        c = np.asarray(drive.columns[key])
        drive.columns[key] = c[(np.arange(c.size) // every) * every]


def _compass_spikes(drive, fraction=0.01, sigma_ut=15.0):
    rng = np.random.default_rng([drive.seed, 5])
    n = len(drive.columns["compass_x"])
    hit = rng.random(n) < fraction
    for key in ("compass_x", "compass_y"):
        drive.columns[key] = np.asarray(drive.columns[key]) + hit * rng.normal(0.0, sigma_ut, n)


def _fixed_hard_iron(drive, offset_ut=3.0):
    angle = np.random.default_rng([drive.seed, 6]).uniform(0.0, 2.0 * np.pi)
    drive.columns["compass_x"] = np.asarray(drive.columns["compass_x"]) + offset_ut * np.cos(angle)
    drive.columns["compass_y"] = np.asarray(drive.columns["compass_y"]) + offset_ut * np.sin(angle)


def _wheel_slip(drive, fraction=0.002, accel=1.5):
    t = np.asarray(drive.truth["time_s"], float)
    speed = np.asarray(drive.truth["speed_mps"], float)
    slipping = np.abs(np.gradient(speed, t)) > accel
    left = sc.unwrap_counter(drive.columns["left_pulses"])
    extra = np.round(np.cumsum(np.where(slipping[1:], np.diff(left) * fraction, 0.0))).astype(np.int64)
    left[1:] += extra
    drive.columns["left_pulses"] = left % 65536


def _spurious_pulses(drive, per_minute=2.0):
    rng = np.random.default_rng([drive.seed, 7])
    t = np.asarray(drive.columns["time_s"], float)
    hits = rng.random(t.size) < per_minute / 60.0 * np.gradient(t)
    left_wheel = rng.random(t.size) < 0.5
    for key, wheel in (("left_pulses", left_wheel), ("right_pulses", ~left_wheel)):
        counter = sc.unwrap_counter(drive.columns[key]) + np.cumsum(hits & wheel)
        drive.columns[key] = counter % 65536


def _counters_held(drive, every):
    """Both counters updated on every ``every``-th sample only and repeated in between (a logger faster than the
    counters' own messages; an FMU master stepping faster than the sensor)."""
    for key in ("left_pulses", "right_pulses"):
        counts = np.asarray(drive.columns[key])
        drive.columns[key] = counts[(np.arange(counts.size) // every) * every]


def _keep_rows(drive, keep):
    """Only the rows ``keep`` selects (a mask or a slice), of the log and of its truth."""
    n = len(drive.columns["time_s"])
    for table in (drive.columns, drive.truth):
        for key, value in table.items():
            if isinstance(value, np.ndarray) and value.shape[:1] == (n,):
                table[key] = value[keep]


def _decimate(drive, every):
    """Every ``every``-th sample of the log and of its truth (a logger at 10 / every Hz)."""
    _keep_rows(drive, slice(None, None, every))


def _time_jitter(drive, jitter_s=0.02):
    rng = np.random.default_rng([drive.seed, 8])
    t = np.asarray(drive.columns["time_s"], float)
    drive.columns["time_s"] = t + rng.uniform(-jitter_s, jitter_s, t.size)


def _dropped_rows(drive, fraction=0.03, gap_s=3.0):
    rng = np.random.default_rng([drive.seed, 9])
    t = np.asarray(drive.columns["time_s"], float)
    keep = rng.random(t.size) >= fraction
    gap_start = rng.uniform(0.3, 0.7) * (t[-1] - t[0]) + t[0]
    keep &= ~((t >= gap_start) & (t < gap_start + gap_s))
    keep[0] = True
    _keep_rows(drive, keep)


def _counter_reset(drive, at=0.5):
    n = len(drive.columns["time_s"])
    i = int(at * n)
    for key in ("left_pulses", "right_pulses"):
        counter = sc.unwrap_counter(drive.columns[key])
        counter[i:] -= counter[i]
        drive.columns[key] = counter % 65536


def _pulse_chatter(drive, per_sample=1, duration_s=2.0, at=0.5):
    """The left counter over-counts by ``per_sample`` pulses on every sample for ``duration_s`` from ``at`` of the
    drive (a chafed sensor cable): below the plausibility guard's per-sample tolerance, a step of the wheel heading."""
    t = np.asarray(drive.columns["time_s"], float)
    i0 = int(np.searchsorted(t, t[0] + at * (t[-1] - t[0])))
    i1 = int(np.searchsorted(t, t[i0] + duration_s))
    extra = np.zeros(t.size, np.int64)
    extra[i0:i1] = per_sample
    drive.columns["left_pulses"] = (sc.unwrap_counter(drive.columns["left_pulses"]) + np.cumsum(extra)) % 65536


def _stuck_wheel(drive, at=0.4, duration_s=5.0):
    t = np.asarray(drive.columns["time_s"], float)
    start = t[0] + at * (t[-1] - t[0])
    stuck = (t >= start) & (t < start + duration_s)
    left = sc.unwrap_counter(drive.columns["left_pulses"])
    lost = np.cumsum(np.where(stuck[1:], np.diff(left), 0))
    left[1:] -= lost
    drive.columns["left_pulses"] = left % 65536


def _coarse_pulses(drive, every=3):
    """Every ``every``-th pulse counted, and the vehicle's dpp (the estimator's parameter) ``every`` times longer."""
    for key in ("left_pulses", "right_pulses"):
        drive.columns[key] = (sc.unwrap_counter(drive.columns[key]) // every) % 65536
    drive.params["dpp_left"] *= every
    drive.params["dpp_right"] *= every


def _scaled_noisy_compass(drive, scale, sigma_ut, stream):
    """Both compass axes times ``scale``, plus white noise of ``sigma_ut`` (µT) from the drive's random ``stream``."""
    rng = np.random.default_rng([drive.seed, stream])
    for key in ("compass_x", "compass_y"):
        c = np.asarray(drive.columns[key], float)
        drive.columns[key] = scale * c + sigma_ut * rng.standard_normal(c.size)


def _compass_noise(drive, sigma_ut=1.0):
    _scaled_noisy_compass(drive, 1.0, sigma_ut, stream=8)


def _weak_field(drive, scale=0.5, sigma_ut=0.25):
    _scaled_noisy_compass(drive, scale, sigma_ut, stream=9)


DISTURBANCES = {"none": lambda drive: None, "compass_lag": _compass_lag, "compass_delay": _compass_delay,
                "compass_hold": _compass_hold,
                "compass_spikes": _compass_spikes, "fixed_hard_iron": _fixed_hard_iron, "wheel_slip": _wheel_slip,
                "spurious_pulses": _spurious_pulses,
                "log_5hz": lambda drive: _decimate(drive, 2), "log_2hz": lambda drive: _decimate(drive, 5),
                "log_1hz": lambda drive: _decimate(drive, 10),
                "time_jitter": _time_jitter, "dropped_rows": _dropped_rows, "counter_reset": _counter_reset,
                "stuck_wheel": _stuck_wheel,
                "stuck_wheel_long": lambda drive: _stuck_wheel(drive, at=0.6, duration_s=10.0),
                "coarse_pulses": _coarse_pulses, "compass_noise": _compass_noise, "weak_field": _weak_field,
                "counters_held_5": lambda drive: _counters_held(drive, 5),
                "counters_held_10": lambda drive: _counters_held(drive, 10),
                "pulse_chatter": _pulse_chatter,
                "burst_over_5": lambda drive: _pulse_chatter(drive, per_sample=5, duration_s=0.45)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="101,104")
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--only", help="comma-separated disturbances to run (default: all)")
    ap.add_argument("--axle", choices=("front", "rear"), default="front", help="the vehicles' wheel sensor axle")
    ap.add_argument("--kalman", action="store_true", help="also the Kalman mode (no fixes), not in the ratio")
    args = ap.parse_args()
    modes = MODES + (("kalman",) if args.kalman else ())
    chosen = DISTURBANCES if not args.only else {k: DISTURBANCES[k] for k in args.only.split(",")}
    seeds = [int(s) for s in args.seeds.split(",")]
    t0 = time.perf_counter()
    base = [sc.make_drive(scenario, "baseline", seed, args.duration, sensor_axle=args.axle)
            for seed in seeds for scenario in sc.SCENARIOS]
    print(f"baseline drives of seeds {seeds} ({len(base)} drives, {args.duration:g} s, {args.axle}-axle wheel "
          f"sensors), heading RMSE after the "
          f"first minute (deg); ratio = default / min(odometer, compass)\n")
    print(f"| disturbance | drive | {' | '.join(modes)} | ratio |\n|---|---|{'---|' * len(modes)}---|")
    for name, disturb in chosen.items():
        drives = []
        for drive in base:
            changed = copy.deepcopy(drive)
            disturb(changed)
            drives.append(changed)
        ratios = []
        for row in ev.evaluate(drives, modes=modes):
            r = row["rmse"]
            ratios.append(row["ratio"])
            print(f"| {name} | {row['name'].replace('/baseline', '')} | "
                  f"{' | '.join(f'{r[m]:.2f}' for m in modes)} | {ratios[-1]:.2f} |", flush=True)
        print(f"| {name} | geometric mean ratio | {'| ' * len(modes)}{np.exp(np.mean(np.log(ratios))):.2f} |",
              flush=True)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
