"""The route of a simulated drive (SPEC §5): road classes, legs, and the kinematics along them.

1. Route: a random sequence of legs per scenario (urban grid with 90° turns and traffic lights,
   rural roads, motorway with gentle curves and interchange loops, parking lot with tight turns
   and reversing into spaces).  Each leg has a length, a steering curvature (dψ per signed metre),
   a speed limit, a direction of travel and an optional stop at its end.
2. Kinematics on a 0.25 m distance grid (``build_route``): curvature smoothed into clothoid-like
   transitions, the speed profile limited by the legs, lateral acceleration and bounded
   acceleration/deceleration (forward/backward passes), time from distance, dwell times at stops;
   heading, position, road grade.

``simulate`` reads the resulting ``Route`` at its sample times and derives the sensors from it.
All vectorized with numpy; the random draws come from the generator the caller passes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

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
LANE_WANDER_DEG = 0.25      # heading wander around the street heading on roads (lane keeping)


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
# route


def _speed(rng, lo, hi, base):
    return float(np.clip(base * rng.uniform(0.93, 1.05), lo, hi))


def _junction_turn(rng, road, radius_range, angle_sigma_deg, k_max, v_cap):
    """A turn of about 90 deg left or right at a junction: radius drawn in ``radius_range`` (m), at most
    the steering's curvature ``k_max``, taken at the road's lateral-acceleration speed (at most ``v_cap``)."""
    radius = rng.uniform(*radius_range)
    angle = math.radians(90.0 + rng.normal(0.0, angle_sigma_deg)) * rng.choice([-1.0, 1.0])
    kappa = math.copysign(min(1.0 / radius, k_max), angle)
    v_turn = min(v_cap, math.sqrt(ROADS[road]["a_lat"] / abs(kappa))) * rng.uniform(0.75, 1.0)
    return Leg(abs(angle / kappa), kappa, v_turn, road)


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
            # tight corners to wide arterial junctions
            turn = _junction_turn(rng, "urban", (8.0, 35.0), 3.0, k_max, v_street)
            legs.append(turn)
            t += turn.length / turn.v_max
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
            turn = _junction_turn(rng, "rural", (12.0, 25.0), 5.0, k_max, math.inf)
            legs.append(turn)
            t += turn.length / turn.v_max + 10.0
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
