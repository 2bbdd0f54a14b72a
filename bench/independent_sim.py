"""Independent vehicle + drive simulator for judging the odocompass estimator.

Written from physics and from SPEC.md / the seed patents only, without reading the
project's own simulator, so that the estimator can be scored on drives it was not
tuned on.  Nothing here is imported from the project.

Model (vehicle frame: x forward, y right, z down, origin at the rear-axle centre;
heading psi clockwise from true north, so a right turn makes psi grow and
D_L - D_R > 0, SPEC section 1):

* Vehicle drawn from the seed: wheel base B, front track T_F (wheel contact patches,
  straight ahead), rear track T_R, Pitman-arm ratio P (the front wheel's contact patch
  sits P*T_F/2 outboard of its king pin, along the wheel's spin axis, so the king pins
  are T_F*(1-P) apart: US 4,788,645 FIG. 4), tyre rolling radii left/right differing by
  0-1.5 %, pulses per revolution, sensor wheels on the front or the rear axle.
* Kinematics: the path curvature kappa(s) and a driver speed controller give the speed
  and the yaw rate; every sensor wheel's rolling distance is the projection of its own
  contact-patch velocity (rigid body + steering motion of the patch about the king pin)
  on its wheel plane, with ideal Ackerman steer angles.  Each front wheel therefore
  travels its own arc; nothing here uses eq. (14).
* Speed effects ("slip"): the rear axle runs at a slip angle a_y / C' (so the
  instantaneous centre of rotation moves forward by V^2 / C'); lateral load transfer
  shrinks the loaded (outer) tyre's rolling radius by g_r * a_y and grows the inner
  one's, which makes D_L - D_R over-read a turn by 1 + (2 g_r / T) V^2 (the seeds'
  velocity coefficient a = 2 g_r / T, written to the parameter file); centrifugal tyre
  growth g_v V^2 (same on both sides).
* Grades: on a slope the road-plane yaw rate is psi_dot * cos(pitch).
* Odometer: integer cumulative counters with a random start and a random phase,
  wrapping at counter_modulus; optional road-roughness noise on each wheel's distance.
* Compass: IGRF-like 3-axis field (horizontal H, dip, declination), world-fixed
  magnetic anomalies (2-10 uT, 10-40 m across, ~1.5 per km) and a few 100-300 m
  disturbed stretches (bridges / tunnels), rotated into the body by heading, pitch
  (grade + squat/dive) and roll (body roll + crossfall); vehicle soft iron (3x3) and
  hard iron; a 2-axis horizontal-plane sensor fixed to the body (so it tilts with the
  car: the dip error on hills), mounted with a small yaw rotation; white noise and
  0.05 uT quantisation.  compass_x is the forward axis, compass_y the LEFT axis, so
  that atan2(compass_y, compass_x) is the magnetic heading of an ideal sensor (SPEC 1).
* Parameter file: the true vehicle (P, B, T_F, T_R, a, dpp_left/right at rest,
  sensor_axle, counter_modulus), the true variation and mounting rotation, and a
  factory compass calibration (X0, Y0, field_magnitude) with a small error.

Routes (15 min at 10 Hz by default): urban, urban_hilly, mixed, highway.

    python bench/independent_sim.py --kind urban --seed 7 --out-dir DIR [--clean]
"""
from __future__ import annotations

import argparse
import json
import math
import os
from dataclasses import dataclass, asdict, field

import numpy as np

from independent_routes import (DS, DT_SIM, KMH, build_highway, build_mixed, build_urban,  # noqa: E402
                                drive_profile, grade_profile, smooth_noise)

KINDS = ("urban", "urban_hilly", "mixed", "highway")
FEATURES = ("anomalies", "hills", "tilt", "slip", "road_noise", "compass_noise",
            "soft_iron", "calib_error", "mount_rotation")
CLEAN_OFF = ("anomalies", "hills", "tilt", "slip", "road_noise", "soft_iron", "calib_error")

LOG_EVERY = 5       # log at 10 Hz


# ----------------------------------------------------------------------------- vehicle
@dataclass
class Vehicle:
    B: float
    T_F: float
    T_R: float
    P: float
    r_left: float            # sensor-wheel rolling radius at rest, m
    r_right: float
    ppr: int                 # pulses per wheel revolution
    sensor_axle: str
    counter_modulus: int
    g_load: float            # rolling-radius change per m/s^2 of lateral acceleration
    c_rear: float            # rear cornering stiffness per unit weight, m/s^2 per rad
    g_speed: float           # centrifugal tyre growth, 1/(m/s)^2
    road_sigma: float        # road-roughness relative noise on each wheel's distance
    k_pitch: float           # rad of nose-up pitch per m/s^2 of acceleration
    k_roll: float            # rad of roll per m/s^2 of lateral acceleration
    # magnetics
    H: float                 # horizontal earth field, uT
    dip_deg: float
    declination_deg: float   # east positive
    hard_iron: list          # [x, y_left] in compass axes, uT
    soft_iron: list          # 3x3, body frame
    mount_rot_deg: float     # sensor x axis rotated clockwise from the car's forward axis
    compass_sigma: float     # uT
    a_true: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def dpp_left(self):
        return 2.0 * math.pi * self.r_left / self.ppr

    @property
    def dpp_right(self):
        return 2.0 * math.pi * self.r_right / self.ppr

    @property
    def T_sensor(self):
        return self.T_F if self.sensor_axle == "front" else self.T_R


def draw_vehicle(rng: np.random.Generator, off: set) -> Vehicle:
    B = rng.uniform(2.45, 3.45)                       # small car .. long-wheelbase van
    T_F = rng.uniform(1.45, 1.72)
    T_R = float(np.clip(T_F + rng.uniform(-0.06, 0.06), 1.40, 1.75))
    P = rng.uniform(0.08, 0.25)
    r0 = rng.uniform(0.285, 0.360)
    mis = rng.uniform(0.0, 0.015) * rng.choice([-1.0, 1.0])
    r_left, r_right = r0 * (1.0 - mis / 2), r0 * (1.0 + mis / 2)
    ppr = int(rng.choice([43, 44, 48, 50, 60, 86, 96, 100]))
    sensor_axle = str(rng.choice(["front", "rear"]))
    counter_modulus = int(rng.choice([65536, 65536, 32768, 4096]))
    T_s = T_F if sensor_axle == "front" else T_R
    # every value is drawn whatever is switched off, so that a switched-off variant
    # of a drive keeps the same vehicle, route and noise
    a_true = float(np.exp(rng.uniform(np.log(3e-5), np.log(2.5e-4))))
    g_load = a_true * T_s / 2.0
    c_rear = rng.uniform(150.0, 300.0)
    g_speed = rng.uniform(1.0e-6, 3.0e-6)
    if "slip" in off:
        a_true, g_load, c_rear, g_speed = 0.0, 0.0, float("inf"), 0.0
    road_sigma = rng.uniform(1e-4, 2.5e-4)
    if "road_noise" in off:
        road_sigma = 0.0
    k_pitch = math.radians(rng.uniform(0.3, 0.6))
    k_roll = math.radians(rng.uniform(0.3, 0.6))
    H = rng.uniform(18.0, 22.0)
    dip = rng.uniform(60.0, 70.0)
    decl = rng.uniform(-12.0, 12.0)
    hard = rng.normal(0.0, 3.0, size=2)
    E = rng.normal(0.0, 0.02, size=(3, 3))
    soft = np.eye(3) if "soft_iron" in off else np.eye(3) + 0.5 * (E + E.T)
    mount = rng.uniform(-3.0, 3.0)
    if "mount_rotation" in off:
        mount = 0.0
    sigma = rng.uniform(0.1, 0.3)
    if "compass_noise" in off:
        sigma = 0.0
    return Vehicle(B=B, T_F=T_F, T_R=T_R, P=P, r_left=r_left, r_right=r_right, ppr=ppr,
                   sensor_axle=sensor_axle, counter_modulus=counter_modulus, g_load=g_load,
                   c_rear=c_rear, g_speed=g_speed, road_sigma=road_sigma, k_pitch=k_pitch,
                   k_roll=k_roll, H=H, dip_deg=dip, declination_deg=decl,
                   hard_iron=hard.tolist(), soft_iron=soft.tolist(), mount_rot_deg=mount,
                   compass_sigma=sigma, a_true=a_true)


# ----------------------------------------------------------------------------- magnetics
def _unit3(rng):
    x = rng.standard_normal(3)
    return x / np.linalg.norm(x)


def anomaly_field(rng, s, s_total, off):
    """World-fixed disturbance (NED, uT) as a function of the distance driven."""
    F = np.zeros((len(s), 3))
    info = {"anomalies": [], "stretches": []}
    n_anom = rng.poisson(1.5 * s_total / 1000.0)
    for _ in range(n_anom):
        s0 = rng.uniform(0.0, s_total)
        width = rng.uniform(10.0, 40.0)
        amp = rng.uniform(2.0, 10.0)
        vec = amp * _unit3(rng)
        F += np.exp(-0.5 * ((s - s0) / (width / 4)) ** 2)[:, None] * vec
        info["anomalies"].append([s0, width, amp])
    n_str = int(rng.integers(2, 5))
    lo = min(300.0, 0.2 * s_total)
    for _ in range(n_str):
        L = rng.uniform(100.0, 300.0)
        s0 = rng.uniform(lo, max(lo + 1.0, s_total - L))
        base = rng.uniform(4.0, 12.0) * _unit3(rng)
        taper = 10.0
        w = np.clip(np.minimum(s - s0, s0 + L - s) / taper, 0.0, 1.0)
        w = 0.5 - 0.5 * np.cos(np.pi * w)
        var = np.zeros((len(s), 3))
        for _ in range(3):
            lam = rng.uniform(8.0, 40.0)
            var += np.sin(2 * np.pi * s / lam + rng.uniform(0, 2 * np.pi))[:, None] * \
                (rng.uniform(1.0, 4.0) * _unit3(rng))
        F += w[:, None] * (base + var)
        info["stretches"].append([s0, L, float(np.linalg.norm(base))])
    if "anomalies" in off:
        return np.zeros((len(s), 3)), {"anomalies": [], "stretches": []}
    return F, info


def body_field(psi, theta, phi, B_ned):
    """B in the body frame (x fwd, y right, z down): C_n^b B_n with C_b^n = Rz(psi) Ry(theta) Rx(phi)."""
    cps, sps = np.cos(psi), np.sin(psi)
    cth, sth = np.cos(theta), np.sin(theta)
    cph, sph = np.cos(phi), np.sin(phi)
    Bn, Be, Bd = B_ned[:, 0], B_ned[:, 1], B_ned[:, 2]
    # yaw: into the heading frame
    x1 = cps * Bn + sps * Be
    y1 = -sps * Bn + cps * Be
    z1 = Bd
    # pitch
    x2 = cth * x1 - sth * z1
    z2 = sth * x1 + cth * z1
    y2 = y1
    # roll
    y3 = cph * y2 + sph * z2
    z3 = -sph * y2 + cph * z2
    return np.stack([x2, y3, z3], axis=1)


def sensor_axes(veh, Bb):
    """Body-frame field -> the 2-axis sensor's (x forward, y LEFT) readings, before hard
    iron and noise: vehicle soft iron, then the sensor's mounting rotation (clockwise)."""
    Bs = Bb @ np.asarray(veh.soft_iron).T
    rho = math.radians(veh.mount_rot_deg)
    xs = Bs[:, 0] * math.cos(rho) + Bs[:, 1] * math.sin(rho)
    ys = -Bs[:, 0] * math.sin(rho) + Bs[:, 1] * math.cos(rho)     # sensor's right axis
    return xs, -ys


# ----------------------------------------------------------------------------- the drive
def simulate(kind, seed, duration=900.0, disable=(), vehicle_seed=None):
    """One drive of ``kind``: its route, road, magnetics and noise drawn from ``seed``, its vehicle from ``seed`` too
    or, given ``vehicle_seed``, from that alone (several drives of one vehicle, as a calibration engineer logs them;
    the drive's own vehicle is still drawn and discarded, so its other streams stay those of ``seed``).
    Returns (log, truth, params, meta)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}")
    off = set(disable)
    bad = off - set(FEATURES)
    if bad:
        raise ValueError(f"unknown feature(s) {sorted(bad)}; known: {FEATURES}")
    streams = [np.random.default_rng([seed, KINDS.index(kind), 20240611, i]) for i in range(6)]
    rng_veh, rng, rng_grade, rng_mag, rng_noise, rng_cal = streams
    veh = draw_vehicle(rng_veh, off)
    if vehicle_seed is not None:
        veh = draw_vehicle(np.random.default_rng([vehicle_seed, 20240611, 99]), off)
    vtop = {"urban": 55, "urban_hilly": 55, "mixed": 95, "highway": 135}[kind] * KMH
    total_len = 1.2 * vtop * duration + 3000.0
    if kind in ("urban", "urban_hilly"):
        route = build_urban(rng, total_len)
    elif kind == "mixed":
        route = build_mixed(rng, total_len)
    else:
        route = build_highway(rng, total_len)
    kappa, vmax = route.arrays()
    n = len(kappa)
    kappa = kappa + 2e-5 * smooth_noise(rng, n, 30.0 / DS)     # roads are never quite straight
    gmax = {"urban": 0.012, "urban_hilly": rng_grade.uniform(0.08, 0.10), "mixed": 0.05,
            "highway": 0.035}[kind]
    grade = grade_profile(rng_grade, n, gmax)
    crossfall = np.clip(0.01 + 0.007 * smooth_noise(rng_grade, n, 100.0 / DS), -0.025, 0.03)
    if "hills" in off:
        grade = np.zeros(n)
    if "tilt" in off:
        crossfall = np.zeros(n)
    a_lat = rng.uniform(2.2, 3.2)
    t, s, v, acc = drive_profile(rng, kappa, vmax, route.stops, duration, a_lat)

    grid = np.arange(n) * DS
    kap = np.interp(s, grid, kappa)
    gr = np.interp(s, grid, grade)
    pitch_g = np.arctan(gr)
    psi0 = rng_veh.uniform(-np.pi, np.pi)
    psi_dot = v * kap                                         # horizontal heading rate
    psi = psi0 + np.concatenate([[0.0], np.cumsum(0.5 * (psi_dot[1:] + psi_dot[:-1]) * DT_SIM)])
    kp = kap * np.cos(pitch_g)                                # road-plane curvature
    r = v * kp                                                # road-plane yaw rate
    a_y = v * r                                               # lateral acceleration, + right
    alpha_r = a_y / veh.c_rear if math.isfinite(veh.c_rear) else np.zeros_like(a_y)
    v_lat = -v * alpha_r                                      # rear axle drifts outwards

    # ---- sensor-wheel rolling speeds
    if veh.sensor_axle == "rear":
        roll_L = v + r * veh.T_R / 2
        roll_R = v - r * veh.T_R / 2
    else:
        p = veh.P * veh.T_F / 2                               # Pitman arm (scrub) offset
        kh = veh.T_F * (1 - veh.P) / 2                        # half king-pin track
        B = veh.B
        dL = np.arctan2(kp * B - alpha_r, 1 + kp * kh)        # ideal Ackerman steer angles
        dR = np.arctan2(kp * B - alpha_r, 1 - kp * kh)
        cLx, cLy = B + p * np.sin(dL), -kh - p * np.cos(dL)   # contact patches
        cRx, cRy = B - p * np.sin(dR), kh + p * np.cos(dR)
        dLdot = np.gradient(dL, DT_SIM)
        dRdot = np.gradient(dR, DT_SIM)
        roll_L = (v - r * cLy) * np.cos(dL) + (v_lat + r * cLx) * np.sin(dL) + p * dLdot
        roll_R = (v - r * cRy) * np.cos(dR) + (v_lat + r * cRx) * np.sin(dR) - p * dRdot
    sgrid = np.arange(0.0, s[-1] + 5.0, 0.25)
    for_side = []
    for _ in range(2):
        nz = smooth_noise(rng_noise, len(sgrid), 2.0 / 0.25)
        for_side.append(1.0 + veh.road_sigma * np.interp(s, sgrid, nz))
    roll_L = roll_L * for_side[0]
    roll_R = roll_R * for_side[1]
    roll_L, roll_R = np.abs(roll_L), np.abs(roll_R)
    reff_L = veh.r_left * (1 + veh.g_speed * v ** 2 - veh.g_load * a_y)
    reff_R = veh.r_right * (1 + veh.g_speed * v ** 2 + veh.g_load * a_y)
    rate_L = roll_L / (2 * np.pi * reff_L) * veh.ppr
    rate_R = roll_R / (2 * np.pi * reff_R) * veh.ppr

    def cum(x):
        return np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * DT_SIM)])

    NL = cum(rate_L) + rng_noise.uniform(0, 1)
    NR = cum(rate_R) + rng_noise.uniform(0, 1)
    M = veh.counter_modulus
    cL0, cR0 = int(rng_noise.integers(0, M)), int(rng_noise.integers(0, M))
    left = (cL0 + np.floor(NL).astype(np.int64)) % M
    right = (cR0 + np.floor(NR).astype(np.int64)) % M

    # ---- position (x east, y north) of the rear-axle centre
    beta = np.arctan2(v_lat, np.maximum(v, 1e-9))
    vh = np.hypot(v, v_lat) * np.cos(pitch_g)
    cx = cum(vh * np.sin(psi + beta))
    cy = cum(vh * np.cos(psi + beta))

    # ---- log at 10 Hz
    idx = np.arange(0, len(t), LOG_EVERY)
    tl = t[idx]
    sl = s[idx]
    F_anom, anom_info = anomaly_field(rng_mag, sl, float(s[-1]) + 1.0, off)
    D = math.radians(veh.declination_deg)
    Z = veh.H * math.tan(math.radians(veh.dip_deg))
    B_ned = np.tile([veh.H * math.cos(D), veh.H * math.sin(D), Z], (len(idx), 1)) + F_anom
    if "tilt" in off:
        theta = pitch_g[idx]
        phi = np.zeros(len(idx))
    else:
        theta = pitch_g[idx] + veh.k_pitch * acc[idx]             # squat / dive
        phi = -veh.k_roll * a_y[idx] + np.arctan(np.interp(sl, grid, crossfall))
    Bb = body_field(psi[idx], theta, phi, B_ned)
    xs, yl = sensor_axes(veh, Bb)
    cxm = xs + veh.hard_iron[0] + rng_noise.normal(0, 1, len(idx)) * veh.compass_sigma
    cym = yl + veh.hard_iron[1] + rng_noise.normal(0, 1, len(idx)) * veh.compass_sigma
    q = 0.05
    cxm = np.round(cxm / q) * q
    cym = np.round(cym / q) * q

    ref = np.degrees(np.angle(np.exp(1j * psi[idx])))
    ref = np.where(ref <= -180.0, ref + 360.0, ref)
    log = {
        "time_s": tl,
        "left_pulses": left[idx],
        "right_pulses": right[idx],
        "compass_x": cxm,
        "compass_y": cym,
        "ref_heading_deg": ref,
    }
    truth = {
        "time_s": tl, "s_m": sl, "speed_mps": v[idx], "accel_mps2": acc[idx],
        "yaw_rate_dps": np.degrees(psi_dot[idx]), "curvature": kap[idx], "grade": gr[idx],
        "pitch_deg": np.degrees(theta), "roll_deg": np.degrees(phi),
        "x_m": cx[idx], "y_m": cy[idx], "heading_unwrapped_deg": np.degrees(psi[idx]),
        "anom_n_uT": F_anom[:, 0], "anom_e_uT": F_anom[:, 1], "anom_d_uT": F_anom[:, 2],
    }
    # ---- the parameter file: true vehicle, factory compass calibration
    soft = np.asarray(veh.soft_iron)
    H_eff = veh.H * 0.5 * (soft[0, 0] + soft[1, 1])
    # a factory calibration (circles on level ground) sees the centre of the horizontal
    # field circle: the hard iron plus the soft iron's coupling of the vertical field
    zx, zy = sensor_axes(veh, np.array([[0.0, 0.0, Z]]))
    X0_true, Y0_true = veh.hard_iron[0] + zx[0], veh.hard_iron[1] + zy[0]
    X0 = X0_true + rng_cal.normal(0.0, 0.4)
    Y0 = Y0_true + rng_cal.normal(0.0, 0.4)
    fm = H_eff * (1.0 + rng_cal.normal(0.0, 0.015))
    if "calib_error" in off:
        X0, Y0, fm = X0_true, Y0_true, H_eff
    params = {
        "sensor_axle": veh.sensor_axle,
        "P": round(veh.P, 6), "B": round(veh.B, 6), "T_F": round(veh.T_F, 6),
        "T_R": round(veh.T_R, 6), "a": float(f"{veh.a_true:.6g}"),
        "dpp_left": float(f"{veh.dpp_left:.9g}"), "dpp_right": float(f"{veh.dpp_right:.9g}"),
        "counter_modulus": veh.counter_modulus,
        "variation_deg": round(veh.declination_deg, 6),
        "X0": round(float(X0), 6), "Y0": round(float(Y0), 6),
        "rotation_deg": round(veh.mount_rot_deg, 6),
        "field_magnitude": round(float(fm), 6),
    }
    meta = {"kind": kind, "seed": seed, "vehicle_seed": vehicle_seed, "duration_s": duration, "disabled": sorted(off),
            "vehicle": asdict(veh), "distance_m": float(s[-1]),
            "n_stops": len([x for x in route.stops if x[0] <= s[-1]]),
            "max_grade": float(np.max(np.abs(gr))), **anom_info}
    return log, truth, params, meta


def _write_csv(path, cols, fmts):
    names = list(cols)
    arr = [cols[k] for k in names]
    with open(path + ".tmp", "w") as f:
        f.write(",".join(names) + "\n")
        fmt = ",".join(fmts[k] for k in names) + "\n"
        for row in zip(*arr):
            f.write(fmt % row)
    os.replace(path + ".tmp", path)


def make_drive(kind, seed, out_dir, *, duration=900.0, clean=False, disable=(), vehicle_seed=None):
    """Simulate one drive; writes DRIVE.csv, its parameter JSON, a truth CSV and a meta JSON.
    ``vehicle_seed``: the vehicle drawn from it (``simulate``), the files tagged ``_v<vehicle_seed>``.
    Returns (csv_path, params_json_path)."""
    off = set(disable) | (set(CLEAN_OFF) if clean else set())
    log, truth, params, meta = simulate(kind, seed, duration, off, vehicle_seed)
    os.makedirs(out_dir, exist_ok=True)
    tag = f"indep_{kind}_s{seed}" + ("" if vehicle_seed is None else f"_v{vehicle_seed}") + \
        ("_clean" if clean else "") + \
        ("" if not disable else "_no-" + "-".join(sorted(set(disable))))
    csv_path = os.path.join(out_dir, tag + ".csv")
    par_path = os.path.join(out_dir, tag + ".params.json")
    _write_csv(csv_path, log, {"time_s": "%.3f", "left_pulses": "%d", "right_pulses": "%d",
                               "compass_x": "%.3f", "compass_y": "%.3f",
                               "ref_heading_deg": "%.6f"})
    _write_csv(os.path.join(out_dir, tag + ".truth.csv"), truth,
               {k: "%.6f" for k in truth})
    with open(par_path, "w") as f:
        json.dump(params, f, indent=1)
    with open(os.path.join(out_dir, tag + ".meta.json"), "w") as f:
        json.dump(meta, f, indent=1, default=float)
    return csv_path, par_path


def write_hidden_mismatch_params(params_path):
    """Beside the drive's parameter file, a copy with dpp_left = dpp_right = their mean (a user who never measured the
    tyres' mismatch: the calibration must find it), ``TAG.hidden.params.json``.  Returns its path."""
    params = _read_params(params_path)
    mean = 0.5 * (params["dpp_left"] + params["dpp_right"])
    return _write_beside(params_path, "hidden", dict(params, dpp_left=mean, dpp_right=mean))


def write_ratio_off_params(params_path, ppm):
    """Beside the drive's parameter file, a copy with dpp_right ``ppm`` parts per million off the tyres' (a file
    identified before the tyres' pressure or wear moved their ratio, or identified to that precision; docs/tuning.md,
    stops 69-70), ``TAG.ratio_off.params.json``.  Returns its path."""
    params = _read_params(params_path)
    return _write_beside(params_path, "ratio_off", dict(params, dpp_right=params["dpp_right"] * (1.0 + 1e-6 * ppm)))


NOT_VEHICLE_KEYS = ("counter_modulus", "variation_deg", "X0", "Y0", "rotation_deg", "field_magnitude")
"""The parameter file's keys that are not the vehicle's: the counters' modulus and the compass's calibration."""


def write_no_vehicle_params(params_path):
    """Beside the drive's parameter file, a copy without the vehicle's parameters (P, B, T_F, T_R, a, dpp_left,
    dpp_right, sensor_axle): only the counters' modulus and the compass's calibration (a user who never identified the
    vehicle; ``odocompass estimate`` then runs the nominal vehicle, ``jaxmodel.for_unidentified_vehicle``),
    ``TAG.no_vehicle.params.json``.  Returns its path."""
    params = _read_params(params_path)
    return _write_beside(params_path, "no_vehicle", {k: v for k, v in params.items() if k in NOT_VEHICLE_KEYS})


def write_no_a_params(params_path):
    """Beside the drive's parameter file, a copy without eq. (8)'s velocity coefficient a (a vehicle measured but for
    a: ``odocompass estimate`` then learns the turn's error at speed, ``jaxmodel.UNKNOWN_VELOCITY_COEFFICIENT``),
    ``TAG.no_a.params.json``.  Returns its path."""
    params = _read_params(params_path)
    return _write_beside(params_path, "no_a", {k: v for k, v in params.items() if k != "a"})


def _read_params(params_path):
    with open(params_path) as f:
        return json.load(f)


def _write_beside(params_path, tag, params):
    """``params`` written beside the drive's parameter file ``TAG.params.json`` as ``TAG.<tag>.params.json``; its
    path."""
    path = params_path[:-len(".params.json")] + f".{tag}.params.json"
    with open(path, "w") as f:
        json.dump(params, f, indent=1)
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kind", choices=KINDS, required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--clean", action="store_true",
                    help="switch off " + ", ".join(CLEAN_OFF) + " (compass white noise stays)")
    ap.add_argument("--disable", default="",
                    help="comma-separated features to switch off: " + ", ".join(FEATURES))
    a = ap.parse_args(argv)
    dis = tuple(x for x in a.disable.split(",") if x)
    c, p = make_drive(a.kind, a.seed, a.out_dir, duration=a.duration, clean=a.clean, disable=dis)
    print(c)
    print(p)


if __name__ == "__main__":
    main()
