"""The robustness scenario matrix (issue 10): drives under conditions the filter was not designed on.

Each drive starts from ``identification.simulate`` for the route, the kinematics and the wheels
(with its own anomalies switched off), for a vehicle drawn per seed far from the defaults
(wheel base, tracks, Pitman ratio, velocity coefficient and pulse size all differ), and then
replaces the compass with a model written for this matrix alone:

* earth field of 18-24 µT horizontal with a dip of 50-70°, rotated into the body frame with
  the simulated pitch and roll (so hills leak the vertical field, the compass is not
  tilt-compensated), white noise of 0.25 µT per axis and 0.05 µT quantization;
* ``baseline`` anomalies: 1.5 per km, 2-10 µT in random 3-D directions, 10-40 m across,
  0-8 m beside the road;

and one condition on top (``CONDITIONS``):

==================  ========================================================================
rotating            anomalies that mostly rotate the field (horizontal, perpendicular to it)
long_disturbance    2-3 stretches of 100-500 m (bridge, tunnel, car park): attenuated and
                    slowly wandering field
hard_iron_shift     the compass's offsets jump by 3-6 µT at 30-70 % of the drive
soft_iron           a symmetric soft-iron matrix: a heading-dependent deviation of 2-5°
hills               grades of 3-7 % over 300-1200 m (dip error on a level-mounted compass)
glitches            pulse glitches: three bursts of 10-30 spurious pulses, two +-3000-count
                    spikes (``glitch_time_s`` is the first one)
dropouts            two compass dropouts of 2-4 minutes (NaN)
garage_start        the drive starts in a garage: the field turned by 60-150 deg and scaled by 0.6-1.0
                    for the first 30-60 s
no_compass          every compass sample NaN
zero_compass        every compass sample 0 (a dead sensor)
wrong_modulus       the counters wrap at 10,000 while the parameters say 65,536
mismatch_<pct>      right wheel's true dpp larger by 0, 0.5, 1, 1.5 or 2.5 %
==================  ========================================================================

Seeds are split: ``TUNING_SEEDS`` for fitting the defaults (``bench/tune_defaults.py``),
``EVALUATION_SEEDS`` for judging them (``bench/bench_scenarios.py``); never both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import sensors
from .simulate import SCENARIOS, simulate

BASE_CONDITIONS = ("baseline", "rotating", "long_disturbance", "hard_iron_shift", "soft_iron", "hills", "glitches",
                   "dropouts", "no_compass", "zero_compass", "wrong_modulus")
MISMATCHES_PCT = (0.0, 0.5, 1.0, 1.5, 2.5)
CONDITIONS = BASE_CONDITIONS + tuple(f"mismatch_{m:g}" for m in MISMATCHES_PCT) + ("garage_start",)
"""Every condition; a new one goes at the end (a drive's random stream is seeded with its condition's index)."""
NO_COMPASS_CONDITIONS = ("no_compass", "zero_compass")
TUNING_SEEDS = (101, 102, 103)
EVALUATION_SEEDS = (201, 202, 203)
WRONG_MODULUS = 10000


@dataclass
class ScenarioDrive:
    """One drive of the matrix: drive-schema columns, truth, and the vehicle's true parameters."""

    scenario: str
    condition: str
    seed: int
    columns: dict[str, np.ndarray]
    truth: dict[str, Any]
    params: dict[str, Any]
    glitch_time_s: float | None = None
    notes: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.scenario}/{self.condition}/{self.seed}"

    @property
    def has_compass(self) -> bool:
        return self.condition not in NO_COMPASS_CONDITIONS


def vehicle(seed: int) -> dict[str, Any]:
    """A vehicle drawn per seed, away from the defaults (B 2.7, T_F 1.55, a 1e-4, dpp 0.02)."""
    rng = np.random.default_rng([int(seed), 7919])
    t_f = float(rng.uniform(1.45, 1.72))
    return {"B": float(rng.uniform(2.45, 3.25)), "T_F": t_f, "T_R": t_f + float(rng.uniform(-0.04, 0.06)),
            "P": float(rng.uniform(0.09, 0.17)), "a": float(rng.uniform(0.3e-4, 4.5e-4)),
            "dpp_left": (dpp := float(rng.uniform(0.014, 0.03))), "dpp_right": dpp}


def _lobes(rng, x, y, s, per_km, amp, diameter, rotate_only, h_dir):
    """Gaussian anomaly lobes placed beside the driven path; returns the NED disturbance (N, 3)."""
    n = rng.poisson(per_km * max(s[-1], 1.0) / 1000.0)
    out = np.zeros((x.size, 3))
    if n == 0:
        return out
    at = rng.uniform(100.0, max(s[-1], 101.0), n)  # distance along the path; the first 100 m stay clean
    idx = np.searchsorted(s, at).clip(0, x.size - 1)
    off = rng.uniform(0.0, 8.0, n) * rng.choice([-1.0, 1.0], n)
    ang = rng.uniform(0, 2 * math.pi, n)
    cx, cy = x[idx] + off * np.cos(ang), y[idx] + off * np.sin(ang)
    radius = rng.uniform(*diameter, n) / 2.0
    a = rng.uniform(*amp, n)
    if rotate_only:  # horizontal and perpendicular to the earth's horizontal field: mostly a rotation
        sign = rng.choice([-1.0, 1.0], n)
        vec = np.stack([-h_dir[1] * sign * a, h_dir[0] * sign * a, np.zeros(n)], axis=1)
    else:
        v = rng.standard_normal((n, 3))
        vec = v / np.linalg.norm(v, axis=1, keepdims=True) * a[:, None]
    for k in range(n):
        near = np.abs(s - at[k]) < 6.0 * radius[k] + 60.0
        r2 = (x[near] - cx[k]) ** 2 + (y[near] - cy[k]) ** 2
        out[near] += np.exp(-r2 / radius[k] ** 2)[:, None] * vec[k]
    return out


def _stretches(rng, s, earth, count, length):
    """Long disturbed stretches: the field scaled by 0.5-0.9 plus a wandering 3-12 µT vector."""
    out = np.zeros((s.size, 3))
    total = s[-1]
    if total < 400.0:
        return out
    for _ in range(count):
        L = rng.uniform(*length)
        start = rng.uniform(150.0, max(total - L, 151.0))
        inside = (s >= start) & (s <= start + L)
        if not np.any(inside):
            continue
        u = (s[inside] - start) / L
        edge = np.clip(np.minimum(u, 1 - u) * L / 15.0, 0.0, 1.0)  # 15 m ramps at both ends
        scale = rng.uniform(0.5, 0.9)
        walk = np.cumsum(rng.standard_normal((inside.sum(), 3)), axis=0)
        walk = walk / (np.abs(walk).max() + 1e-9) * rng.uniform(3.0, 12.0)
        out[inside] = edge[:, None] * ((scale - 1.0) * earth[None, :] + walk)
    return out


def unwrap_counter(counter, modulus=65536):
    """A pulse counter that wraps at ``modulus`` as one that does not (int64): each step is taken as the
    shortest way round, so steps of up to half the modulus either way are kept."""
    c = np.asarray(counter, np.int64)
    half = modulus // 2
    return np.concatenate([[c[0]], c[0] + np.cumsum((np.diff(c) + half) % modulus - half)])


def _glitch(rng, left, right, t, speed):
    """Bursts and spikes on the counters (int64 arrays, changed in place).

    Single spurious pulses are left out on purpose: one pulse is within the quantization of
    every sample and no check can tell it from motion (it turns the wheel heading by dpp/T).
    """
    moving = np.flatnonzero(speed > 3.0)
    moving = moving[(moving > 600) & (moving < t.size - 50)]
    if moving.size < 10:
        return None
    picks = np.sort(rng.choice(moving, size=5, replace=False))
    for k, i in enumerate(picks):
        counter = left if k % 2 == 0 else right
        if k < 3:   # burst: spurious pulses counted from this sample on
            counter[i:] += int(rng.integers(10, 31))
        else:       # spike: one sample reads 3000 counts off, then the counter is right again
            counter[i] += 3000 * int(rng.choice([-1, 1]))
    return float(t[picks[0]])


def make_drive(scenario: str, condition: str, seed: int, duration_s: float = 900.0,
               fixes_sigma: float | None = 4.0, sensor_axle: str = "front") -> ScenarioDrive:
    """One drive of the matrix (see the module docstring); deterministic in (scenario, condition, seed).
    ``sensor_axle``: the axle of the vehicle's wheel sensors ("rear": no Ackerman geometry; the outside bench)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}")
    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; expected one of {', '.join(CONDITIONS)}")
    p = dict(vehicle(seed), sensor_axle=sensor_axle)
    mismatch = float(condition.split("_")[1]) / 100.0 if condition.startswith("mismatch_") else 0.0
    columns, truth = simulate(scenario, duration_s, seed, params=p, fixes_sigma=fixes_sigma,
                              dpp_mismatch=mismatch, anomalies=False)
    rng = np.random.default_rng([int(seed), SCENARIOS.index(scenario), CONDITIONS.index(condition), 31337])
    field_rng = np.random.default_rng([int(seed), SCENARIOS.index(scenario), 4242])  # same field in every condition
    t = np.asarray(truth["time_s"], np.float64)
    x, y = np.asarray(truth["x_m"]), np.asarray(truth["y_m"])
    psi = np.asarray(truth["heading_rad"])
    pitch = np.radians(truth["pitch_deg"])
    roll = np.radians(truth["roll_deg"])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])

    horizontal = field_rng.uniform(18.0, 24.0)
    dip = math.radians(field_rng.uniform(50.0, 70.0))
    earth = np.array([horizontal, 0.0, horizontal * math.tan(dip)])
    h_dir = np.array([1.0, 0.0])
    disturbance = _lobes(field_rng, x, y, s, 1.5, (2.0, 10.0), (10.0, 40.0), False, h_dir)
    notes: dict[str, Any] = {"field_ut": horizontal, "dip_deg": math.degrees(dip), "vehicle": p}
    X0 = Y0 = 0.0
    soft = np.eye(2)
    if condition == "rotating":
        disturbance += _lobes(rng, x, y, s, 3.0, (2.0, 8.0), (10.0, 40.0), True, h_dir)
    elif condition == "long_disturbance":
        disturbance += _stretches(rng, s, earth, int(rng.integers(2, 4)), (100.0, 500.0))
    elif condition == "hills":
        grade = np.zeros_like(s)
        for _ in range(3):
            grade += math.radians(rng.uniform(1.5, 3.0)) * np.sin(2 * math.pi * s / rng.uniform(300, 1200)
                                                                 + rng.uniform(0, 2 * math.pi))
        pitch = pitch + grade
    elif condition == "soft_iron":
        e1, e2 = rng.uniform(0.03, 0.07) * rng.choice([-1, 1]), rng.uniform(0.01, 0.05) * rng.choice([-1, 1])
        soft = np.array([[1.0 + e1, e2], [e2, 1.0 - e1]])
        notes["soft_iron"] = soft.tolist()

    cx, cy = sensors.compass_reading(psi, pitch, roll, disturbance_ned=disturbance, horizontal=horizontal,
                                     vertical=earth[2])
    cx, cy = soft[0, 0] * cx + soft[0, 1] * cy, soft[1, 0] * cx + soft[1, 1] * cy
    if condition == "hard_iron_shift":
        when = rng.uniform(0.3, 0.7) * t[-1]
        ang = rng.uniform(0, 2 * math.pi)
        mag = rng.uniform(3.0, 6.0)
        after = t >= when
        X0, Y0 = mag * math.cos(ang), mag * math.sin(ang)
        cx, cy = cx + np.where(after, X0, 0.0), cy + np.where(after, Y0, 0.0)
        notes["hard_iron_shift"] = {"time_s": when, "X0": X0, "Y0": Y0}
    if condition == "garage_start":
        # The drive starts inside a garage: its steel turns the field by 60-150 deg and scales it by 0.6-1.0
        # until the car has left (30-60 s), so the first compass samples start the wheel heading wrong (FIG. 8B).
        leave = t[0] + rng.uniform(30.0, 60.0)
        turn = math.radians(rng.uniform(60.0, 150.0)) * rng.choice([-1.0, 1.0])
        scale = rng.uniform(0.6, 1.0)
        inside = t < leave
        rc, rs = scale * math.cos(turn), scale * math.sin(turn)
        cx, cy = np.where(inside, rc * cx - rs * cy, cx), np.where(inside, rs * cx + rc * cy, cy)
        notes["garage_start"] = {"leave_s": leave - t[0], "turn_deg": math.degrees(turn), "scale": scale}
    noise = rng.standard_normal((t.size, 2)) * 0.25
    cx = np.round((cx + noise[:, 0]) / 0.05) * 0.05
    cy = np.round((cy + noise[:, 1]) / 0.05) * 0.05
    if condition == "dropouts":
        for _ in range(2):
            a0 = rng.uniform(0.15, 0.8) * t[-1]
            gone = (t >= a0) & (t < a0 + rng.uniform(120.0, 240.0))
            cx[gone] = np.nan
            cy[gone] = np.nan
    elif condition == "no_compass":
        cx[:] = np.nan
        cy[:] = np.nan
    elif condition == "zero_compass":
        cx[:] = 0.0
        cy[:] = 0.0
    columns["compass_x"], columns["compass_y"] = cx, cy
    columns["map_valid"] = np.zeros_like(columns["map_valid"])
    columns["compass_unreliable_area"] = np.zeros_like(columns["compass_unreliable_area"])

    glitch_time = None
    left = np.asarray(columns["left_pulses"], np.int64).copy()
    right = np.asarray(columns["right_pulses"], np.int64).copy()
    if condition == "glitches":
        unwrapped = [unwrap_counter(c) for c in (left, right)]
        notes["pulses_without_glitches"] = (left, right)
        glitch_time = _glitch(rng, unwrapped[0], unwrapped[1], t, np.asarray(truth["speed_mps"]))
        left, right = unwrapped[0] % 65536, unwrapped[1] % 65536
    elif condition == "wrong_modulus":
        left, right = (unwrap_counter(c) % WRONG_MODULUS for c in (left, right))
    columns["left_pulses"], columns["right_pulses"] = left, right
    truth_params = dict(truth["params"])
    return ScenarioDrive(scenario, condition, int(seed), columns, truth, truth_params, glitch_time, notes)


def without_glitches(drive: ScenarioDrive) -> ScenarioDrive:
    """The glitched drive with its counters as they were before the glitches: the same compass
    samples, noise included, so that the difference of the two is the glitches' alone."""
    left, right = drive.notes["pulses_without_glitches"]
    columns = {**drive.columns, "left_pulses": left, "right_pulses": right}
    notes = {k: v for k, v in drive.notes.items() if k != "pulses_without_glitches"}
    return ScenarioDrive(drive.scenario, "glitches_removed", drive.seed, columns, drive.truth, drive.params,
                         drive.glitch_time_s, notes)


def project_drive(scenario: str, seed: int, duration_s: float = 900.0) -> ScenarioDrive:
    """A drive of the project's own simulator as it is (its anomalies, map and default vehicle)."""
    columns, truth = simulate(scenario, duration_s, seed, fixes_sigma=4.0)
    return ScenarioDrive(scenario, "project", int(seed), columns, truth, dict(truth["params"]))


def matrix(seeds, scenarios=SCENARIOS, conditions=CONDITIONS, duration_s: float = 900.0):
    """Every (scenario, condition, seed) drive, in that nesting order (a generator)."""
    for seed in seeds:
        for scenario in scenarios:
            for condition in conditions:
                yield make_drive(scenario, condition, seed, duration_s)
