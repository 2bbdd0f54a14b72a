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

Steps 1 and 2 up to the distance grid (``build_route``) are ``identification.simulate_route``;
this module reads the route at the sample times, adds body roll and pitch, derives the sensors
(steps 3 and 4) and writes the files.

The truth (heading, position, speed, curvature, pitch, anomaly field) is returned and written
beside the drive as ``<stem>.truth.csv`` plus ``<stem>.truth.json`` (true parameters, scenario,
seed, duration, dpp_mismatch).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import numpy as np

from . import sensors
from .errors import OdoCompassError
# Route, Leg, build_route, GENERATORS, SPEED_RANGES and LANE_WANDER_DEG are re-exported from here.
from .simulate_route import (  # noqa: F401
    GENERATORS, GRID_M, LANE_WANDER_DEG, ROAD_NAMES, ROADS, SPEED_RANGES, Leg, Route, _make_route, _smooth_noise,
    build_route)

SCENARIOS = ("urban", "highway", "mixed", "parking")
SAMPLE_PERIOD_S = 0.1
PITCH_PER_ACCEL_DEG = 0.25  # body pitch (nose up) per m/s² of longitudinal acceleration
ROLL_PER_ACCEL_DEG = 0.5    # body roll (outwards) per m/s² of lateral acceleration
MAP_ERROR_DEG = 0.3         # digitization error of a street's map heading
FIX_MODELS = ("gnss", "white")
FIX_CORRELATION_S = 30.0     # correlation time of the correlated half of "gnss" fix errors
REF_NOISE_DEG = 0.1         # GNSS/INS reference heading: white + correlated parts, each this sigma
COMPASS_NOISE_UT = 0.35
START_CLEAR_M = 150.0       # no anomaly lobe centred this close to the start of the route


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
# the simulator


def sample_times(duration_s, rng, period=SAMPLE_PERIOD_S, jitter=0.004, drop_prob=0.003):
    """10 Hz sample times with uniform jitter of +-``jitter`` s and rarely a dropped sample."""
    n = max(int(round(duration_s / period)), 2)
    t = period * np.arange(n) + 0.005 + rng.uniform(-jitter, jitter, n)
    keep = rng.random(n) >= drop_prob
    keep[:2] = True
    return t[keep]


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
    _check_arguments(scenario, duration_s, dpp_mismatch, fixes_sigma, fixes_model)
    p = true_params(params)
    seq = np.random.SeedSequence([int(seed), SCENARIOS.index(scenario)])
    rng_route, rng_wheel, rng_compass, rng_anom, rng_ref = (np.random.default_rng(s) for s in seq.spawn(5))
    k_max = max_steering_curvature(p)
    route = _make_route(scenario, duration_s, rng_route, k_max)
    smp = _sample_kinematics(route, duration_s, rng_route)
    wheels = _wheel_pulses(smp, p, dpp_mismatch, rng_wheel)
    mag = _compass(route, smp, p, anomalies, faults, rng_anom, rng_compass)
    columns = _columns(route, smp, wheels, mag, fixes_sigma, fixes_model, rng_ref)
    truth = {
        "time_s": columns["time_s"],
        **_truth_series(smp, wheels, mag),
        "params": p,
        "scenario": scenario,
        "seed": int(seed),
        "duration_s": float(duration_s),
        "dpp_mismatch": float(dpp_mismatch),
        "true_dpp_left": wheels.dpp_left,
        "true_dpp_right": wheels.dpp_right,
        "field_horizontal_ut": mag.horizontal,
        "n_anomalies": mag.n_anomalies,
        "fixes_sigma": fixes_sigma,
        "fixes_model": fixes_model if fixes_sigma is not None else None,
        "anomalies": bool(anomalies),
        "faults": bool(faults),
    }
    return columns, truth


def _check_arguments(scenario, duration_s, dpp_mismatch, fixes_sigma, fixes_model) -> None:
    """Refuse an unknown scenario or fixes model and out-of-range duration, mismatch or fix sigma."""
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


class _Samples(NamedTuple):
    """The route read at the sample times (one entry per sample)."""

    t: np.ndarray          # sample times, s
    dt: np.ndarray         # time since the previous sample (the first: SAMPLE_PERIOD_S)
    s_k: np.ndarray        # distance along the route, m
    speed: np.ndarray
    psi: np.ndarray        # true heading, rad
    x: np.ndarray
    y: np.ndarray
    sig: np.ndarray        # signed travelled distance, m
    kappa: np.ndarray      # heading change per signed metre
    node: np.ndarray       # grid interval containing s_k
    direction: np.ndarray  # +1 forward, -1 reverse
    pitch: np.ndarray      # rad
    roll: np.ndarray       # rad
    road: np.ndarray       # index into ROAD_NAMES


def _sample_kinematics(route, duration_s, rng) -> _Samples:
    """Position, heading, speed, curvature, road class and body pitch/roll at jittered 10 Hz sample times."""
    t = sample_times(duration_s, rng)
    s_k = np.interp(t, route.t_knots, route.s_knots)
    speed = np.interp(t, route.t_knots, route.v_knots)
    g = route.s
    kappa = np.interp(s_k, g, route.kappa)
    node = np.minimum(np.floor(s_k / GRID_M).astype(np.int64), g.size - 1)  # interval containing s_k
    direction = route.direction[node]
    moving = speed > 0.05
    a_long = np.where(moving, np.interp(s_k, g, route.accel), 0.0) * direction
    pitch = np.interp(s_k, g, route.grade) + np.radians(PITCH_PER_ACCEL_DEG) * a_long
    a_lat = kappa * direction * speed**2  # + towards the right
    roll = -np.radians(ROLL_PER_ACCEL_DEG) * a_lat + _smooth_noise(rng, s_k, 50.0, math.radians(0.3))
    return _Samples(
        t=t, dt=np.diff(t, prepend=t[0] - SAMPLE_PERIOD_S), s_k=s_k, speed=speed, psi=np.interp(s_k, g, route.psi),
        x=np.interp(s_k, g, route.x), y=np.interp(s_k, g, route.y), sig=np.interp(s_k, g, route.sigma),
        kappa=kappa, node=node, direction=direction, pitch=pitch, roll=roll, road=route.road[node])


class _Wheels(NamedTuple):
    """Pulse counters and the wheel model's truth."""

    left_pulses: np.ndarray
    right_pulses: np.ndarray
    curvature: np.ndarray  # ΔD/AD of the wheel model
    dpp_left: float        # true distance per pulse
    dpp_right: float


def _wheel_pulses(smp: _Samples, p, dpp_mismatch, rng) -> _Wheels:
    """Wrapping pulse counts of both wheels: the seed's wheel model inverted, plus differential slip."""
    AD = np.diff(smp.sig, prepend=smp.sig[0])
    d_psi = np.diff(smp.psi, prepend=smp.psi[0])
    dD, curvature = sensors.differential_distance(
        d_psi, AD, smp.dt, P=p["P"], B=p["B"], T_F=p["T_F"], T_R=p["T_R"], a=p["a"],
        front=p["sensor_axle"] == "front")
    slip_err, _ = sensors.SlipModel().errors(AD, rng)
    d_left, d_right = sensors.split_wheels(AD, dD + slip_err)
    dist_left, dist_right = np.cumsum(d_left), np.cumsum(d_right)
    dpp_left_true = p["dpp_left"]
    dpp_right_true = p["dpp_right"] * (1.0 + dpp_mismatch)
    modulus = int(round(p["counter_modulus"]))
    offsets = rng.integers(0, modulus, size=2)
    phases = rng.random(2)
    left_pulses = sensors.count_pulses(dist_left, dpp_left_true, modulus, offsets[0], phases[0])
    right_pulses = sensors.count_pulses(dist_right, dpp_right_true, modulus, offsets[1], phases[1])
    return _Wheels(left_pulses, right_pulses, curvature, dpp_left_true, dpp_right_true)


class _Compass(NamedTuple):
    """Compass readings and the magnetic truth."""

    x: np.ndarray            # µT, NaN at simulated dropouts
    y: np.ndarray
    disturbance: np.ndarray  # anomaly field (N, 3) µT north/east/down, without the transients
    unreliable: np.ndarray   # bool: near a lobe known to the map (compass_unreliable_area)
    n_anomalies: int
    horizontal: float        # horizontal earth field, µT


def _compass(route, smp: _Samples, p, anomalies, faults, rng_anom, rng_compass) -> _Compass:
    """Compass readings along the drive: earth field plus anomalies and transients, noise, dropouts."""
    field = sensors.AnomalyField()
    n_anomalies = 0
    if anomalies:
        n_anomalies = _place_anomalies(field, route, float(smp.s_k[-1]), rng_anom)
    disturbance, unreliable = field.evaluate(smp.x, smp.y)
    transients = _transients(smp, disturbance, anomalies, rng_anom)
    horizontal = sensors.horizontal_field(p["field_magnitude"])
    n = smp.t.size
    noise = COMPASS_NOISE_UT * rng_compass.standard_normal((n, 2))
    compass_x, compass_y = sensors.compass_reading(
        smp.psi, smp.pitch, smp.roll, disturbance_ned=disturbance + transients, horizontal=horizontal,
        variation_deg=p["variation_deg"], rotation_deg=p["rotation_deg"], X0=p["X0"], Y0=p["Y0"],
        deviation_deg=p["deviation_deg"], noise=noise)
    if faults:
        bad = rng_compass.choice(np.arange(10, n), size=min(6, max(n - 10, 0)), replace=False)
        compass_x[bad] = np.nan
        compass_y[bad[::2]] = np.nan
    return _Compass(compass_x, compass_y, disturbance, unreliable, n_anomalies, horizontal)


def _transients(smp: _Samples, disturbance, anomalies, rng):
    """Short field disturbances (passing trucks, trams), drawn per road class at that class's rate."""
    transients = np.zeros_like(disturbance)
    if anomalies:
        for r_i, r in enumerate(ROAD_NAMES):
            sel = smp.road == r_i
            if np.any(sel) and ROADS[r]["transients_per_s"] > 0.0:
                tr = sensors.Transients(ROADS[r]["transients_per_s"]).evaluate(smp.t, rng)
                transients += np.where(sel[:, None], tr, 0.0)
    return transients


def _columns(route, smp: _Samples, wheels: _Wheels, mag: _Compass, fixes_sigma, fixes_model, rng_ref) -> dict:
    """The drive's columns, rounded to the logged resolutions; map, reference heading and fixes drawn here."""
    map_heading, map_valid = _map(route, smp.node, rng_ref)
    ref_noise = _reference_noise(smp.dt, rng_ref)
    columns: dict[str, np.ndarray] = {
        "time_s": np.round(smp.t, 6),
        "left_pulses": wheels.left_pulses,
        "right_pulses": wheels.right_pulses,
        "compass_x": np.round(mag.x, 3),  # 1 nT resolution
        "compass_y": np.round(mag.y, 3),
        "ref_heading_deg": np.round(np.degrees(sensors.wrap(smp.psi + ref_noise)), 5),
        "map_heading_deg": np.round(np.degrees(map_heading), 5),
        "map_valid": map_valid.astype(np.int64),
        "compass_unreliable_area": mag.unreliable.astype(np.int64),
    }
    if fixes_sigma is not None:
        columns.update(_fixes(smp.t, smp.x, smp.y, fixes_sigma, smp.road, rng_ref, correlated=fixes_model == "gnss"))
    return columns


def _reference_noise(dt, rng):
    """Error of the GNSS/INS reference heading, rad: white plus correlated (20 s), each REF_NOISE_DEG."""
    n = dt.size
    return (math.radians(REF_NOISE_DEG) * rng.standard_normal(n)
            + sensors.ou_filter(dt, 20.0, math.radians(REF_NOISE_DEG), rng.standard_normal(n))[0])


def _truth_series(smp: _Samples, wheels: _Wheels, mag: _Compass) -> dict:
    """The per-sample truth (after time_s): heading, position, speed, curvatures, attitude, anomaly, road."""
    heading = sensors.wrap(smp.psi)
    return {
        "heading_rad": heading,
        "heading_deg": np.degrees(heading),
        "x_m": smp.x,
        "y_m": smp.y,
        "speed_mps": smp.speed,
        "curvature": wheels.curvature,
        "kappa_per_m": smp.kappa * smp.direction,
        "pitch_deg": np.degrees(smp.pitch),
        "roll_deg": np.degrees(smp.roll),
        "anomaly_ut": np.linalg.norm(mag.disturbance[:, :2], axis=1),
        "road": np.array(ROAD_NAMES)[smp.road],
    }


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
    from .console import info  # information lines: stderr, silenced by -q like every command's

    info(f"simulated {args.scenario} drive: {n} samples, {columns['time_s'][-1]:.1f} s, {dist / 1000:.2f} km, "
         f"{truth['n_anomalies']} anomalies, {time.perf_counter() - t0:.2f} s")
    info(f"wrote {out}, {csv_path.name}, {json_path.name}")
    return 0
