"""Synthetic drives: ``odocompass simulate`` and ``simulate(...)`` (SPEC §5).

A drive is built in four steps, all vectorized with numpy (a 40-minute drive takes a fraction
of a second):

1. Route: a random sequence of legs per scenario (urban grid with 90° turns and traffic lights,
   rural roads, motorway with gentle curves and interchange loops, parking lot with tight turns
   and reversing into spaces).  Each leg has a length, a steering curvature (dψ per signed metre),
   a speed limit, a direction of travel and an optional stop at its end.
2. Kinematics on a 0.25 m distance grid: curvature smoothed into clothoid-like transitions, the
   speed profile limited by the legs, lateral acceleration and bounded acceleration/deceleration
   (forward/backward passes), time from distance, dwell times at stops; heading, position, road
   grade and body roll/pitch.  The grid is read at 10 Hz sample times with timing jitter and
   rare dropped samples.
3. Wheels: the seed's model inverted (US 4,788,645 eq. 8 and 14): per sample, the true heading
   change over AD gives ΔD = Δψ T(c) (1 + a V²), c = ΔD/AD by fixed point, so the estimator run
   with the true parameters integrates the true heading; plus differential slip.  Pulses are
   counted with the true distance per pulse (``dpp_mismatch`` makes the right wheel's differ
   from the parameter file) and wrap at counter_modulus.
4. Compass, map, reference heading and position fixes from ``identification.sensors``.

The truth (heading, position, speed, curvature, pitch, anomaly field) is returned and written
beside the drive as ``<stem>.truth.csv`` plus ``<stem>.truth.json`` (true parameters, scenario,
seed, duration, dpp_mismatch).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from . import sensors
from .errors import OdoCompassError

SCENARIOS = ("urban", "highway", "mixed", "parking")
SAMPLE_PERIOD_S = 0.1
GRID_M = 0.25

# Per road class: lateral acceleration limit (m/s²), acceleration and deceleration (m/s²), curvature
# transition length (m, the clothoid between a straight and an arc), road grade sigma (deg) and
# correlation length (m), anomalies per km and the kind probabilities, compass transients per s.
ROADS: dict[str, dict[str, Any]] = {
    "urban": dict(a_lat=2.5, accel=2.0, decel=2.5, transition=6.0, grade_deg=0.9, grade_m=250.0,
                  anomalies_per_km=3.0, kinds={"building": 0.35, "rail": 0.15, "truck": 0.3, "bridge": 0.2},
                  transients_per_s=1 / 60, two_way=0.5),
    "rural": dict(a_lat=2.5, accel=1.5, decel=2.0, transition=30.0, grade_deg=1.5, grade_m=400.0,
                  anomalies_per_km=0.8, kinds={"bridge": 0.3, "rail": 0.3, "truck": 0.2, "building": 0.2},
                  transients_per_s=1 / 120, two_way=0.5),
    "highway": dict(a_lat=2.0, accel=1.0, decel=1.5, transition=80.0, grade_deg=1.0, grade_m=600.0,
                    anomalies_per_km=0.5, kinds={"bridge": 0.7, "rail": 0.1, "building": 0.2},
                    transients_per_s=1 / 90, two_way=0.0),
    "parking": dict(a_lat=1.5, accel=0.8, decel=1.0, transition=1.5, grade_deg=0.3, grade_m=60.0,
                    anomalies_per_km=6.0, kinds={"truck": 0.6, "building": 0.4},
                    transients_per_s=0.0, two_way=0.0),
}
ROAD_NAMES = tuple(ROADS)
SPEED_RANGES = {"urban": (0.0, 15.0), "highway": (22.0, 36.0), "rural": (15.0, 25.0), "parking": (0.5, 3.0)}
PITCH_PER_ACCEL_DEG = 0.25  # body pitch (nose up) per m/s² of longitudinal acceleration
ROLL_PER_ACCEL_DEG = 0.5    # body roll (outwards) per m/s² of lateral acceleration
LANE_WANDER_DEG = 0.25      # heading wander around the street heading on roads (lane keeping)
MAP_ERROR_DEG = 0.3         # digitization error of a street's map heading
FIX_MODELS = ("gnss", "white")
FIX_CORRELATION_S = 30.0     # correlation time of the correlated half of "gnss" fix errors
REF_NOISE_DEG = 0.1         # GNSS/INS reference heading: white + correlated parts, each this sigma
COMPASS_NOISE_UT = 0.35
START_CLEAR_M = 150.0       # no anomaly lobe centred this close to the start of the route


@dataclass
class Leg:
    length: float          # m of path
    kappa: float           # steering curvature dψ/dσ, 1/m (+ = right turn when driving forward)
    v_max: float           # m/s
    road: str = "urban"
    direction: int = 1     # +1 forward, -1 reverse
    stop_s: float = 0.0    # dwell at the end (s)
    straight: bool = False  # a mapped street segment (map heading valid on it)


# ----------------------------------------------------------------------------------------------
# parameters


def true_params(params=None) -> dict[str, Any]:
    """Full flat parameter dict (JSON style): defaults of jaxmodel.params, updated by ``params``.

    ``params`` may be None, a dict of JSON keys, or a jaxmodel Params.  Unknown keys are refused.
    """
    from jaxmodel.params import PARAMETER_SPECS, PARAMETER_TABLE, ParameterError

    out: dict[str, Any] = {p.key: p.default for p in PARAMETER_TABLE}
    if params is None:
        return _plain(out)
    if hasattr(params, "_asdict"):  # a Params NamedTuple
        from jaxmodel.params import params_to_dict

        return _plain(params_to_dict(params))
    for key, value in dict(params).items():
        if key == "report":
            continue
        if key not in PARAMETER_SPECS:
            raise ParameterError(f"unknown parameter key {key!r}")
        out[key] = value
    return _plain(out)


def _plain(d: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if k == "sensor_axle":
            out[k] = "front" if v in ("front", 1, 1.0, True) else "rear"
        elif k == "deviation_deg":
            out[k] = [float(x) for x in np.asarray(v, dtype=np.float64).reshape(-1)]
        else:
            out[k] = float(v)
    return out


def max_steering_curvature(p: Mapping[str, Any], fraction=0.9) -> float:
    """Largest path curvature (1/m) the route uses: ΔD/AD stays at ``fraction`` of eq. (14)'s maximum."""
    c = fraction * sensors.max_curvature(p["B"], p["T_F"])
    if p["sensor_axle"] == "front":
        return float(c / sensors.effective_track(c, p["P"], p["B"], p["T_F"]))
    return float(min(c / p["T_R"], c / sensors.effective_track(c, p["P"], p["B"], p["T_F"])))


# ----------------------------------------------------------------------------------------------
# route


def _speed(rng, lo, hi, base):
    return float(np.clip(base * rng.uniform(0.93, 1.05), lo, hi))


def _urban_legs(rng, budget_s, k_max):
    legs: list[Leg] = []
    t = 0.0
    v_street = _speed(rng, 6.0, 15.0, rng.choice([8.3, 11.1, 13.9]))
    while t < budget_s:
        length = rng.uniform(100.0, 300.0)
        if rng.random() < 0.2:  # a bend in the street
            angle = math.radians(rng.uniform(10.0, 35.0)) * rng.choice([-1.0, 1.0])
            radius = rng.uniform(60.0, 200.0)
            l1 = rng.uniform(0.3, 0.6) * length
            legs.append(Leg(l1, 0.0, v_street, "urban", straight=True))
            legs.append(Leg(abs(angle) * radius, math.copysign(1.0 / radius, angle), v_street, "urban"))
            length -= l1
            t += l1 / v_street + abs(angle) * radius / v_street
        stop = 0.0
        u = rng.random()
        if u < 0.35:
            stop = rng.uniform(3.0, 30.0)   # traffic light
        elif u < 0.42:
            stop = rng.uniform(1.0, 3.0)    # stop sign, pedestrians
        legs.append(Leg(length, 0.0, v_street, "urban", stop_s=stop, straight=True))
        t += length / (0.7 * v_street) + stop
        if rng.random() < 0.55:  # 90° turn at the intersection
            radius = rng.uniform(8.0, 35.0)  # tight corners to wide arterial junctions
            angle = math.radians(90.0 + rng.normal(0.0, 3.0)) * rng.choice([-1.0, 1.0])
            kappa = math.copysign(min(1.0 / radius, k_max), angle)
            v_turn = min(v_street, math.sqrt(ROADS["urban"]["a_lat"] / abs(kappa))) * rng.uniform(0.75, 1.0)
            legs.append(Leg(abs(angle / kappa), kappa, v_turn, "urban"))
            t += abs(angle / kappa) / v_turn
            v_street = _speed(rng, 6.0, 15.0, rng.choice([8.3, 11.1, 13.9]))
    return legs


def _rural_legs(rng, budget_s, k_max):
    legs: list[Leg] = []
    t = 0.0
    v_road = _speed(rng, 15.0, 25.0, rng.uniform(17.0, 24.0))
    while t < budget_s:
        length = rng.uniform(300.0, 1500.0)
        stop = rng.uniform(2.0, 10.0) if rng.random() < 0.1 else 0.0  # junction
        legs.append(Leg(length, 0.0, v_road, "rural", stop_s=stop, straight=True))
        t += length / v_road + stop
        if stop > 0.0:
            radius = rng.uniform(12.0, 25.0)
            angle = math.radians(90.0 + rng.normal(0.0, 5.0)) * rng.choice([-1.0, 1.0])
            kappa = math.copysign(min(1.0 / radius, k_max), angle)
            v_turn = math.sqrt(ROADS["rural"]["a_lat"] / abs(kappa)) * rng.uniform(0.75, 1.0)
            legs.append(Leg(abs(angle / kappa), kappa, v_turn, "rural"))
            t += abs(angle / kappa) / v_turn + 10.0
            v_road = _speed(rng, 15.0, 25.0, rng.uniform(17.0, 24.0))
        else:
            radius = rng.uniform(80.0, 600.0)
            angle = math.radians(rng.uniform(10.0, 90.0)) * rng.choice([-1.0, 1.0])
            v_curve = min(v_road, math.sqrt(ROADS["rural"]["a_lat"] * radius))
            legs.append(Leg(abs(angle) * radius, math.copysign(1.0 / radius, angle), v_curve, "rural"))
            t += abs(angle) * radius / v_curve
    return legs


def _highway_legs(rng, budget_s, k_max):
    legs: list[Leg] = []
    t = 0.0
    v_cruise = _speed(rng, 22.0, 36.0, rng.uniform(25.0, 34.0))
    while t < budget_s:
        length = rng.uniform(500.0, 3000.0)
        legs.append(Leg(length, 0.0, v_cruise, "highway", straight=True))
        t += length / v_cruise
        if rng.random() < 0.06:  # interchange: a loop ramp of ~270°
            radius = rng.uniform(50.0, 80.0)
            angle = math.radians(rng.uniform(250.0, 280.0)) * rng.choice([-1.0, 1.0])
            v_loop = math.sqrt(ROADS["highway"]["a_lat"] * radius)
            legs.append(Leg(abs(angle) * radius, math.copysign(1.0 / radius, angle), v_loop, "highway"))
            t += abs(angle) * radius / v_loop + 20.0
        else:
            radius = rng.uniform(400.0, 2000.0)
            angle = math.radians(rng.uniform(5.0, 45.0)) * rng.choice([-1.0, 1.0])
            legs.append(Leg(abs(angle) * radius, math.copysign(1.0 / radius, angle), v_cruise, "highway"))
            t += abs(angle) * radius / v_cruise
        if rng.random() < 0.5:  # traffic changes the cruise speed
            v_cruise = _speed(rng, 22.0, 36.0, rng.uniform(24.0, 35.0))
    return legs


def _parking_legs(rng, budget_s, k_max):
    legs: list[Leg] = []
    t = 0.0
    while t < budget_s:
        length = rng.uniform(15.0, 60.0)
        v_aisle = rng.uniform(2.0, 3.0)
        stop = rng.uniform(2.0, 8.0) if rng.random() < 0.3 else 0.0
        legs.append(Leg(length, 0.0, v_aisle, "parking", stop_s=stop))
        t += length / (0.6 * v_aisle) + stop
        side = rng.choice([-1.0, 1.0])
        if rng.random() < 0.35:  # reverse into a space, wait, drive out
            k_in = side * rng.uniform(0.7, 0.95) * k_max
            k_out = -side * rng.uniform(0.6, 0.9) * k_max
            angle = math.radians(rng.uniform(80.0, 95.0))
            legs[-1].stop_s = max(legs[-1].stop_s, rng.uniform(1.0, 3.0))
            legs.append(Leg(angle / abs(k_in), k_in, rng.uniform(0.5, 1.0), "parking", direction=-1,
                            stop_s=rng.uniform(5.0, 30.0)))
            legs.append(Leg(angle / abs(k_out), k_out, rng.uniform(0.6, 1.2), "parking"))
            t += 2 * angle / abs(k_in) / 0.6 + 40.0
        else:  # turn into the next aisle (90°) or back down the parallel one (180°)
            kappa = side * rng.uniform(0.7, 0.95) * k_max
            angle = math.radians(rng.choice([90.0, 180.0]) + rng.normal(0.0, 4.0))
            legs.append(Leg(angle / abs(kappa), kappa, rng.uniform(0.6, 1.5), "parking"))
            t += angle / abs(kappa) / 0.8
    return legs


def _mixed_legs(rng, budget_s, k_max):
    legs: list[Leg] = []
    t = 0.0
    blocks = [(_urban_legs, (60.0, 180.0)), (_rural_legs, (120.0, 300.0)), (_highway_legs, (180.0, 420.0)),
              (_rural_legs, (120.0, 300.0))]
    i = 0
    while t < budget_s:
        make, (lo, hi) = blocks[i % len(blocks)]
        block_t = rng.uniform(lo, hi)
        legs.extend(make(rng, block_t, k_max))
        t += block_t
        i += 1
    return legs


GENERATORS = {"urban": _urban_legs, "highway": _highway_legs, "mixed": _mixed_legs, "parking": _parking_legs}


# ----------------------------------------------------------------------------------------------
# kinematics


def _smooth_noise(rng, s, scale_m, sigma, step_m=None):
    """Zero-mean Gaussian-smoothed noise over s (correlation length ~scale_m), std ``sigma``."""
    if sigma == 0.0 or s.size == 0:
        return np.zeros_like(s)
    step = step_m or max(scale_m / 8.0, GRID_M)
    n = int(math.ceil((s[-1] - s[0]) / step)) + 1
    half = int(math.ceil(3 * scale_m / step))
    white = rng.standard_normal(n + 2 * half)
    k = np.exp(-0.5 * (np.arange(-half, half + 1) * step / scale_m) ** 2)
    k /= math.sqrt(np.sum(k * k))
    coarse = np.convolve(white, k, mode="valid")
    return sigma * np.interp(s, s[0] + step * np.arange(n), coarse[:n])


def _box_smooth(values, half_width):
    """Centered moving average with a per-node half width (in nodes): clothoid-like ramps."""
    c = np.concatenate([[0.0], np.cumsum(values)])
    n = values.size
    i = np.arange(n)
    lo = np.clip(i - half_width, 0, n)
    hi = np.clip(i + half_width + 1, 0, n)
    return (c[hi] - c[lo]) / (hi - lo)


@dataclass
class Route:
    s: np.ndarray          # grid of path length, m
    leg: np.ndarray        # leg index per node
    kappa: np.ndarray      # smoothed steering curvature, 1/m
    direction: np.ndarray  # +1 / -1
    road: np.ndarray       # road class index per node (ROAD_NAMES)
    v: np.ndarray          # speed at the node when passing, m/s
    t_knots: np.ndarray    # time knots of the s(t) relation (stops duplicate a node)
    s_knots: np.ndarray
    v_knots: np.ndarray
    psi_road: np.ndarray   # street heading (without lane wander), rad
    psi: np.ndarray        # vehicle heading, rad (continuous, unwrapped)
    x: np.ndarray
    y: np.ndarray
    sigma: np.ndarray      # signed travelled distance, m
    accel: np.ndarray      # longitudinal acceleration at the node, m/s²
    grade: np.ndarray      # road pitch along the path, rad
    legs: list


def build_route(legs: list[Leg], rng, start_moving=False, start_dwell=2.0, heading0=0.0) -> Route:
    # leg ends snapped to the grid, so a stop (and a change of direction) sits exactly on a node
    ends = np.round(np.cumsum([lg.length for lg in legs]) / GRID_M) * GRID_M
    n = int(ends[-1] / GRID_M) + 1
    s = np.arange(n) * GRID_M
    leg = np.minimum(np.searchsorted(ends, s + 0.5 * GRID_M, side="right"), len(legs) - 1)  # leg of interval i..i+1
    kap_raw = np.array([lg.kappa for lg in legs])[leg]
    direction = np.array([lg.direction for lg in legs], dtype=np.float64)[leg]
    road = np.array([ROAD_NAMES.index(lg.road) for lg in legs])[leg]
    trans = np.array([ROADS[r]["transition"] for r in ROAD_NAMES])[road]
    kappa = _box_smooth(kap_raw, np.round(0.5 * trans / GRID_M).astype(np.int64))

    # speed limit: legs (with a little driver variation), lateral acceleration, stops
    v_leg = np.array([lg.v_max for lg in legs])[leg] * (1.0 - np.abs(_smooth_noise(rng, s, 150.0, 0.04)))
    a_lat = np.array([ROADS[r]["a_lat"] for r in ROAD_NAMES])[road]
    v_lim = np.minimum(v_leg, np.sqrt(a_lat / np.maximum(np.abs(kappa), 1e-9)))
    dwell = np.zeros(n)
    for j, lg in enumerate(legs):
        reverse_next = j + 1 < len(legs) and legs[j + 1].direction != lg.direction
        stop = max(lg.stop_s, 1.5 if reverse_next else 0.0)
        if stop > 0.0 and j + 1 < len(legs):
            i = min(int(round(ends[j] / GRID_M)), n - 1)
            v_lim[i] = 0.0
            dwell[i] += stop
    if not start_moving:
        v_lim[0] = 0.0
        dwell[0] += start_dwell
    accel = np.array([ROADS[r]["accel"] for r in ROAD_NAMES])[road]
    decel = np.array([ROADS[r]["decel"] for r in ROAD_NAMES])[road]
    A = np.concatenate([[0.0], np.cumsum(2.0 * accel[:-1] * GRID_M)])
    v2 = np.minimum.accumulate(v_lim**2 - A) + A
    Bc = np.concatenate([[0.0], np.cumsum(2.0 * decel[::-1][:-1] * GRID_M)])
    v2 = (np.minimum.accumulate(v2[::-1] - Bc) + Bc)[::-1]
    v = np.sqrt(np.maximum(v2, 0.0))
    vsum = np.maximum(v[1:] + v[:-1], 1e-3)
    t_arrive = np.concatenate([[0.0], np.cumsum(2.0 * GRID_M / vsum)]) + np.concatenate([[0.0], np.cumsum(dwell)[:-1]])
    stops = np.flatnonzero(dwell > 0.0)
    t_knots = np.concatenate([t_arrive, t_arrive[stops] + dwell[stops]])
    s_knots = np.concatenate([s, s[stops]])
    v_knots = np.concatenate([v, v[stops]])
    order = np.lexsort((np.concatenate([np.zeros(n), np.ones(stops.size)]), t_knots))
    t_knots, s_knots, v_knots = t_knots[order], s_knots[order], v_knots[order]

    a_long = np.concatenate([(v2[1:] - v2[:-1]) / (2.0 * GRID_M), [0.0]])
    # heading and position over each grid interval with that interval's direction of travel
    d_int = direction[:-1]
    psi_road = heading0 + np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * d_int * GRID_M)])
    psi = psi_road.copy()
    on_road = np.array([r != "parking" for r in ROAD_NAMES])[road]
    psi += np.where(on_road, _smooth_noise(rng, s, 20.0, math.radians(LANE_WANDER_DEG)), 0.0)
    psi_mid = 0.5 * (psi[1:] + psi[:-1])
    x = np.concatenate([[0.0], np.cumsum(d_int * np.sin(psi_mid) * GRID_M)])
    y = np.concatenate([[0.0], np.cumsum(d_int * np.cos(psi_mid) * GRID_M)])
    sigma = np.concatenate([[0.0], np.cumsum(d_int * GRID_M)])
    grade = np.zeros(n)
    for r_i, r in enumerate(ROAD_NAMES):
        if np.any(road == r_i):
            g = _smooth_noise(rng, s, ROADS[r]["grade_m"], math.radians(ROADS[r]["grade_deg"]))
            grade = np.where(road == r_i, g, grade)
    grade = _box_smooth(grade, np.full(n, int(20.0 / GRID_M)))  # no grade steps between road classes
    return Route(s, leg, kappa, direction, road, v, t_knots, s_knots, v_knots, psi_road, psi, x, y, sigma,
                 a_long, grade * direction, legs)


def _make_route(scenario, duration_s, rng, k_max):
    gen = GENERATORS[scenario]
    budget = 1.3 * duration_s + 60.0
    for _ in range(8):
        legs = gen(rng, budget, k_max)
        route = build_route(legs, rng, start_moving=(scenario == "highway"),
                            heading0=rng.uniform(-math.pi, math.pi))
        if route.t_knots[-1] >= duration_s + 1.0:
            return route
        budget *= 2.0
    raise RuntimeError("route generation did not reach the requested duration")


def sample_times(duration_s, rng, period=SAMPLE_PERIOD_S, jitter=0.004, drop_prob=0.003):
    """10 Hz sample times with uniform jitter of +-``jitter`` s and rarely a dropped sample."""
    n = max(int(round(duration_s / period)), 2)
    t = period * np.arange(n) + 0.005 + rng.uniform(-jitter, jitter, n)
    keep = rng.random(n) >= drop_prob
    keep[:2] = True
    return t[keep]


# ----------------------------------------------------------------------------------------------
# the simulator


def simulate(scenario: str, duration_s: float, seed: int, params=None, fixes_sigma: float | None = None,
             dpp_mismatch: float = 0.0, anomalies: bool = True, faults: bool = False, fixes_model: str = "gnss"):
    """Simulate one drive.  Returns (columns in the drive schema, truth dict).

    columns: time_s, left_pulses, right_pulses (int64), compass_x, compass_y (µT), ref_heading_deg,
    map_heading_deg, map_valid, compass_unreliable_area (int64 flags), and with ``fixes_sigma``
    fix_east_m, fix_north_m, fix_valid (1 Hz).  truth: time_s, heading_rad, heading_deg, x_m, y_m,
    speed_mps, curvature (ΔD/AD of the wheel model), kappa_per_m, pitch_deg, roll_deg,
    anomaly_ut (|anomaly field|), params (dict of true parameters), scenario, seed, duration_s,
    dpp_mismatch, true_dpp_left/right, n_anomalies, fixes_sigma, fixes_model.
    ``faults=True`` adds a few NaN compass samples (sensor dropouts).  ``fixes_model`` is the
    error of the fixes, each axis sigma = ``fixes_sigma``: "gnss" (half of the variance white, half
    correlated over 30 s, as multipath and atmosphere make a receiver's) or "white" (independent
    Gaussian errors, the assumption of US 4,680,715 claim 1).
    """
    if scenario not in SCENARIOS:
        raise OdoCompassError(f"unknown scenario {scenario!r}; expected one of {', '.join(SCENARIOS)}")
    if not duration_s > 0.0 or not math.isfinite(duration_s):
        raise OdoCompassError(f"--duration must be a positive number of seconds, got {duration_s}")
    if not -0.5 < dpp_mismatch < 0.5:
        raise OdoCompassError(f"--dpp-mismatch must be a small relative error in (-0.5, 0.5), got {dpp_mismatch}")
    if fixes_sigma is not None and not fixes_sigma >= 0.0:
        raise OdoCompassError(f"--fixes-sigma must be >= 0 m, got {fixes_sigma}")
    if fixes_model not in FIX_MODELS:
        raise OdoCompassError(f"unknown fixes model {fixes_model!r}; expected one of {', '.join(FIX_MODELS)}")
    p = true_params(params)
    seq = np.random.SeedSequence([int(seed), SCENARIOS.index(scenario)])
    rng_route, rng_wheel, rng_compass, rng_anom, rng_ref = (np.random.default_rng(s) for s in seq.spawn(5))
    k_max = max_steering_curvature(p)
    route = _make_route(scenario, duration_s, rng_route, k_max)

    # --- sample the kinematics -------------------------------------------------------------
    t = sample_times(duration_s, rng_route)
    s_k = np.interp(t, route.t_knots, route.s_knots)
    speed = np.interp(t, route.t_knots, route.v_knots)
    g = route.s
    psi = np.interp(s_k, g, route.psi)
    x = np.interp(s_k, g, route.x)
    y = np.interp(s_k, g, route.y)
    sig = np.interp(s_k, g, route.sigma)
    kappa = np.interp(s_k, g, route.kappa)
    node = np.minimum(np.floor(s_k / GRID_M).astype(np.int64), g.size - 1)  # interval containing s_k
    direction = route.direction[node]
    moving = speed > 0.05
    a_long = np.where(moving, np.interp(s_k, g, route.accel), 0.0) * direction
    pitch = np.interp(s_k, g, route.grade) + np.radians(PITCH_PER_ACCEL_DEG) * a_long
    a_lat = kappa * direction * speed**2  # + towards the right
    roll = -np.radians(ROLL_PER_ACCEL_DEG) * a_lat + _smooth_noise(rng_route, s_k, 50.0, math.radians(0.3))
    road = route.road[node]

    # --- wheels: the seed's model inverted, slip, pulses ---------------------------------------
    AD = np.diff(sig, prepend=sig[0])
    d_psi = np.diff(psi, prepend=psi[0])
    dt = np.diff(t, prepend=t[0] - SAMPLE_PERIOD_S)
    dD, curvature = sensors.differential_distance(
        d_psi, AD, dt, P=p["P"], B=p["B"], T_F=p["T_F"], T_R=p["T_R"], a=p["a"], front=p["sensor_axle"] == "front")
    slip_err, _ = sensors.SlipModel().errors(AD, rng_wheel)
    d_left, d_right = sensors.split_wheels(AD, dD + slip_err)
    dist_left, dist_right = np.cumsum(d_left), np.cumsum(d_right)
    dpp_left_true = p["dpp_left"]
    dpp_right_true = p["dpp_right"] * (1.0 + dpp_mismatch)
    modulus = int(round(p["counter_modulus"]))
    offsets = rng_wheel.integers(0, modulus, size=2)
    phases = rng_wheel.random(2)
    left_pulses = sensors.count_pulses(dist_left, dpp_left_true, modulus, offsets[0], phases[0])
    right_pulses = sensors.count_pulses(dist_right, dpp_right_true, modulus, offsets[1], phases[1])

    # --- anomalies along the route, compass ----------------------------------------------------
    field = sensors.AnomalyField()
    n_anomalies = 0
    if anomalies:
        n_anomalies = _place_anomalies(field, route, float(s_k[-1]), rng_anom)
    disturbance, unreliable = field.evaluate(x, y)
    transients = np.zeros_like(disturbance)
    if anomalies:
        for r_i, r in enumerate(ROAD_NAMES):
            sel = road == r_i
            if np.any(sel) and ROADS[r]["transients_per_s"] > 0.0:
                tr = sensors.Transients(ROADS[r]["transients_per_s"]).evaluate(t, rng_anom)
                transients += np.where(sel[:, None], tr, 0.0)
    fm = p["field_magnitude"]
    horizontal = fm if fm > 0.0 else sensors.DEFAULT_FIELD_UT
    noise = COMPASS_NOISE_UT * rng_compass.standard_normal((t.size, 2))
    compass_x, compass_y = sensors.compass_reading(
        psi, pitch, roll, disturbance_ned=disturbance + transients, horizontal=horizontal,
        variation_deg=p["variation_deg"], rotation_deg=p["rotation_deg"], X0=p["X0"], Y0=p["Y0"],
        deviation_deg=p["deviation_deg"], noise=noise)
    if faults:
        bad = rng_compass.choice(np.arange(10, t.size), size=min(6, max(t.size - 10, 0)), replace=False)
        compass_x[bad] = np.nan
        compass_y[bad[::2]] = np.nan

    # --- map, reference heading, fixes --------------------------------------------------------
    map_heading, map_valid = _map(route, node, rng_ref)
    ref_noise = (math.radians(REF_NOISE_DEG) * rng_ref.standard_normal(t.size)
                 + sensors.ou_filter(dt, 20.0, math.radians(REF_NOISE_DEG), rng_ref.standard_normal(t.size))[0])
    heading = sensors.wrap(psi)
    columns: dict[str, np.ndarray] = {
        "time_s": np.round(t, 6),
        "left_pulses": left_pulses,
        "right_pulses": right_pulses,
        "compass_x": np.round(compass_x, 3),  # 1 nT resolution
        "compass_y": np.round(compass_y, 3),
        "ref_heading_deg": np.round(np.degrees(sensors.wrap(psi + ref_noise)), 5),
        "map_heading_deg": np.round(np.degrees(map_heading), 5),
        "map_valid": map_valid.astype(np.int64),
        "compass_unreliable_area": unreliable.astype(np.int64),
    }
    if fixes_sigma is not None:
        columns.update(_fixes(t, x, y, fixes_sigma, road, rng_ref, correlated=fixes_model == "gnss"))

    truth = {
        "time_s": columns["time_s"],
        "heading_rad": heading,
        "heading_deg": np.degrees(heading),
        "x_m": x,
        "y_m": y,
        "speed_mps": speed,
        "curvature": curvature,
        "kappa_per_m": kappa * direction,
        "pitch_deg": np.degrees(pitch),
        "roll_deg": np.degrees(roll),
        "anomaly_ut": np.linalg.norm(disturbance[:, :2], axis=1),
        "road": np.array(ROAD_NAMES)[road],
        "params": p,
        "scenario": scenario,
        "seed": int(seed),
        "duration_s": float(duration_s),
        "dpp_mismatch": float(dpp_mismatch),
        "true_dpp_left": dpp_left_true,
        "true_dpp_right": dpp_right_true,
        "field_horizontal_ut": horizontal,
        "n_anomalies": n_anomalies,
        "fixes_sigma": fixes_sigma,
        "fixes_model": fixes_model if fixes_sigma is not None else None,
        "anomalies": bool(anomalies),
        "faults": bool(faults),
    }
    return columns, truth


def _place_anomalies(field, route, s_end, rng):
    """Anomalies along the driven route: Poisson per km by road class, kinds by road class.

    None within the first START_CLEAR_M of the route: the drive starts where the compass is
    clean (as a navigation system stores its heading at a known place), so the odometer mode,
    which starts from the first compass sample, starts right.
    """
    n = 0
    start = 0.0
    for lg in route.legs:
        if start > s_end + 200.0:
            break
        cfg = ROADS[lg.road]
        count = rng.poisson(cfg["anomalies_per_km"] * lg.length / 1000.0)
        kinds = list(cfg["kinds"])
        probs = np.array([cfg["kinds"][k] for k in kinds])
        for _ in range(count):
            s_a = start + rng.uniform(0.0, lg.length)
            if s_a < START_CLEAR_M:
                continue
            i = min(int(s_a / GRID_M), route.s.size - 1)
            kind = kinds[rng.choice(len(kinds), p=probs / probs.sum())]
            lateral = 0.0 if kind == "bridge" else rng.uniform(-6.0, 6.0)
            c, r, v, k = sensors.AnomalyField.draw(rng, kind, (route.x[i], route.y[i]), route.psi_road[i], lateral)
            field.add(c, r, v, k)
            n += 1
        start += lg.length
    return n


def _map(route, node, rng):
    """Street heading on straight mapped legs (map_valid = 1), outside the curvature transitions.

    The map stores a street as a polyline of one direction: on two-way streets that is, at random,
    the opposite of the driving direction (the selector takes either, FIG. 8F).  Each street
    carries a digitization error of MAP_ERROR_DEG.
    """
    n_legs = len(route.legs)
    err = np.radians(MAP_ERROR_DEG) * rng.standard_normal(n_legs)
    flip = np.array([rng.random() < ROADS[lg.road]["two_way"] for lg in route.legs])
    straight = np.array([lg.straight for lg in route.legs])
    leg = route.leg[node]
    nxt = np.minimum(node + 1, route.s.size - 1)
    valid = straight[leg] & (np.abs(route.kappa[node]) < 1e-9) & (np.abs(route.kappa[nxt]) < 1e-9)
    heading = sensors.wrap(route.psi_road[node] + err[leg] + np.where(flip[leg], math.pi, 0.0))
    return np.where(valid, heading, 0.0), valid


def _fixes(t, x, y, sigma, road, rng, correlated=True):
    """1 Hz GNSS position fixes, per axis sigma: correlated (multipath, tau FIX_CORRELATION_S) plus
    white error, each sigma/sqrt(2); or (``correlated=False``) white error only."""
    sec = np.floor(t)
    first = np.concatenate([[True], sec[1:] != sec[:-1]])
    idx = np.flatnonzero(first)
    dt_fix = np.diff(t[idx], prepend=t[idx[0]] - 1.0)
    # Both models take the same draws (white, then correlated, per axis), so the outages drawn
    # next are the same for both and only the error differs.
    white, colored = [], []
    for _ in range(2):
        white.append(rng.standard_normal(idx.size))
        colored.append(rng.standard_normal(idx.size))
    if correlated:
        part = sigma / math.sqrt(2.0)
        err = np.stack([part * w + sensors.ou_filter(dt_fix, FIX_CORRELATION_S, part, c)[0]
                        for w, c in zip(white, colored)])
    else:
        err = sigma * np.stack(white)
    urban = road[idx] == ROAD_NAMES.index("urban")
    ok = rng.random(idx.size) >= np.where(urban, 0.05, 0.01)  # outages (urban canyons, bridges)
    east = np.zeros(t.size)
    north = np.zeros(t.size)
    valid = np.zeros(t.size, np.int64)
    east[idx] = np.where(ok, np.round(x[idx] + err[0], 3), 0.0)
    north[idx] = np.where(ok, np.round(y[idx] + err[1], 3), 0.0)
    valid[idx] = ok.astype(np.int64)
    return {"fix_east_m": east, "fix_north_m": north, "fix_valid": valid}


# ----------------------------------------------------------------------------------------------
# files and the command


def truth_paths(drive_path) -> tuple[Path, Path]:
    """``<stem>.truth.csv`` and ``<stem>.truth.json`` beside the drive file."""
    p = Path(drive_path)
    stem = p.name[: -len(p.suffix)] if p.suffix else p.name
    return p.with_name(stem + ".truth.csv"), p.with_name(stem + ".truth.json")


TRUTH_COLUMNS = ("time_s", "heading_deg", "x_m", "y_m", "speed_mps", "curvature", "kappa_per_m", "pitch_deg",
                 "roll_deg", "anomaly_ut")


def write_truth(drive_path, truth) -> tuple[Path, Path]:
    csv_path, json_path = truth_paths(drive_path)
    data = np.column_stack([np.asarray(truth[c], dtype=np.float64) for c in TRUTH_COLUMNS])
    fmt = ["%.6f", "%.6f", "%.4f", "%.4f", "%.5f", "%.8g", "%.8g", "%.4f", "%.4f", "%.4f"]
    header = ",".join(TRUTH_COLUMNS)
    np.savetxt(csv_path, data, delimiter=",", fmt=fmt, header=header, comments="")
    meta = {k: truth[k] for k in ("params", "scenario", "seed", "duration_s", "dpp_mismatch", "true_dpp_left",
                                  "true_dpp_right", "field_horizontal_ut", "n_anomalies", "fixes_sigma",
                                  "fixes_model", "anomalies", "faults")}
    meta["drive"] = Path(drive_path).name
    meta["truth_csv"] = csv_path.name
    meta["note"] = ("heading_deg true (clockwise from true north); curvature = dD/AD of the wheel model "
                    "(US 4,788,645); kappa_per_m = heading change per signed metre; anomaly_ut = |horizontal "
                    "anomaly field|")
    json_path.write_text(json.dumps(meta, indent=2) + "\n")
    return csv_path, json_path


def main(args) -> int:
    from .drive_log import write_drive

    if args.fixes_model is not None and args.fixes_sigma is None:
        raise OdoCompassError(f"--fixes-model {args.fixes_model} needs --fixes-sigma M (the drive has no fixes without it)")
    from .diagnostics import checked_params  # issue 11: outputs checked before the work, parameters as estimate
    from .outputs import check_drive_outputs, staged

    outs = check_drive_outputs(args.out, truth_paths, inputs=[("the parameter file", args.params)])
    params = None
    if args.params:
        from jaxmodel.params import params_to_dict

        params = params_to_dict(checked_params(args.params)[0])
    t0 = time.perf_counter()
    columns, truth = simulate(args.scenario, float(args.duration), int(args.seed), params=params,
                              fixes_sigma=args.fixes_sigma, dpp_mismatch=float(args.dpp_mismatch),
                              anomalies=not args.no_anomalies, fixes_model=args.fixes_model or "gnss")
    with staged(outs) as tmps:  # the drive and its truth files appear together or not at all
        write_truth(write_drive(tmps[0], columns), truth)
    out, csv_path, json_path = outs
    n = columns["time_s"].size
    dist = float(np.sum(np.abs(np.diff(truth["x_m"]) + 1j * np.diff(truth["y_m"]))))
    print(f"simulated {args.scenario} drive: {n} samples, {columns['time_s'][-1]:.1f} s, {dist / 1000:.2f} km, "
          f"{truth['n_anomalies']} anomalies, {time.perf_counter() - t0:.2f} s")
    print(f"wrote {out}, {csv_path.name}, {json_path.name}")
    return 0
