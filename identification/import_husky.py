"""The Husky importer (Clearpath Husky, robot_localization test1.bag): ``odocompass import husky``.

Split from ``identification.importers`` (issue 11), which documents the conversion choices and
re-exports these names.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from .errors import OdoCompassError
from .importers import (CAMBRIDGE_2015, COUNTER_MODULUS, HUSKY_DPP, HUSKY_IMU_MOUNT_YPR,
                        HUSKY_SEPARATION_MULTIPLIER, HUSKY_TOPIC_FIX, HUSKY_TOPIC_IMU, HUSKY_TOPIC_ODOM,
                        HUSKY_TRACK, HUSKY_WHEELBASE, HUSKY_WHEEL_SEPARATION, _circular_stats_deg,
                        _interp_angle_deg, _rot_x, _rot_y, _rot_z, cumulative_trapezoid, pulses_from_distance,
                        quat_to_matrix, refuse_unbridgeable, wrap_deg)


def _stamp(msg) -> float:
    return float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)


def read_husky_bag(path) -> dict[str, np.ndarray]:
    """Raw arrays of the three topics (header stamps, s): odom (t, v, omega, x, y, yaw),
    imu (t, qw, qx, qy, qz, wx, wy, wz), fix (t, lat, lon, alt, status)."""
    path = Path(path)
    if not path.is_file():
        raise OdoCompassError(f"{path}: Husky bag not found")
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:  # pragma: no cover - a dependency of the project
        raise OdoCompassError("the 'rosbags' package is needed to read ROS bags (pip install rosbags)") from None
    odo, imu, fix = [], [], []
    try:
        with AnyReader([path]) as reader:
            topics = {c.topic for c in reader.connections}
            for need in (HUSKY_TOPIC_ODOM, HUSKY_TOPIC_IMU):
                if need not in topics:
                    listed = ", ".join(sorted(topics))
                    raise OdoCompassError(f"{path}: topic {need} not in the bag (topics: {listed})")
            conns = [c for c in reader.connections if c.topic in (HUSKY_TOPIC_ODOM, HUSKY_TOPIC_IMU, HUSKY_TOPIC_FIX)]
            for conn, _t, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == HUSKY_TOPIC_ODOM:
                    tw = msg.twist.twist
                    q = msg.pose.pose.orientation
                    odo.append((_stamp(msg), tw.linear.x, tw.angular.z, msg.pose.pose.position.x,
                                msg.pose.pose.position.y, 2.0 * math.atan2(q.z, q.w)))
                elif conn.topic == HUSKY_TOPIC_IMU:
                    o, w = msg.orientation, msg.angular_velocity
                    imu.append((_stamp(msg), o.w, o.x, o.y, o.z, w.x, w.y, w.z))
                else:
                    fix.append((_stamp(msg), msg.latitude, msg.longitude, msg.altitude, msg.status.status))
    except OdoCompassError:
        raise
    except Exception as exc:
        raise OdoCompassError(f"{path}: cannot read as a ROS 1 bag: {' '.join(str(exc).split())}") from None
    out = {"odom": np.array(odo, dtype=np.float64).reshape(-1, 6),
           "imu": np.array(imu, dtype=np.float64).reshape(-1, 8),
           "fix": np.array(fix, dtype=np.float64).reshape(-1, 5)}
    for name in ("odom", "imu"):
        if len(out[name]) < 2:
            raise OdoCompassError(f"{path}: fewer than two {name} messages")
        out[name] = out[name][np.argsort(out[name][:, 0], kind="stable")]
    if len(out["fix"]):
        out["fix"] = out["fix"][np.argsort(out["fix"][:, 0], kind="stable")]
    return out


def husky_imu_yaw(imu: np.ndarray) -> np.ndarray:
    """Yaw (rad, unwrapped) of base_link, counter-clockwise about up, from the IMU orientation and the mounting."""
    yaw, pitch, roll = HUSKY_IMU_MOUNT_YPR
    base_from_imu = _rot_z(yaw) @ _rot_y(pitch) @ _rot_x(roll)
    world_from_base = quat_to_matrix(imu[:, 1:5]) @ base_from_imu.T
    return np.unwrap(np.arctan2(world_from_base[:, 1, 0], world_from_base[:, 0, 0]))


def husky_gyro_yaw_rate(imu: np.ndarray) -> np.ndarray:
    """Yaw rate (rad/s, counter-clockwise about up) of base_link from the IMU's angular velocity."""
    yaw, pitch, roll = HUSKY_IMU_MOUNT_YPR
    base_from_imu = _rot_z(yaw) @ _rot_y(pitch) @ _rot_x(roll)
    return (imu[:, 5:8] @ base_from_imu.T)[:, 2]


def local_east_north(lat_deg, lon_deg, lat0_deg, lon0_deg) -> tuple[np.ndarray, np.ndarray]:
    """Metres east/north of (lat0, lon0) on the WGS-84 ellipsoid's local radii (fine over a few km)."""
    a, f = 6378137.0, 1.0 / 298.257223563
    e2 = f * (2.0 - f)
    lat0 = math.radians(lat0_deg)
    s = math.sin(lat0)
    rn = a / math.sqrt(1.0 - e2 * s * s)
    rm = rn * (1.0 - e2) / (1.0 - e2 * s * s)
    east = np.deg2rad(np.asarray(lon_deg, dtype=np.float64) - lon0_deg) * rn * math.cos(lat0)
    north = np.deg2rad(np.asarray(lat_deg, dtype=np.float64) - lat0_deg) * rm
    return east, north


def gps_course_check(t, heading_deg, fix_t, east, north, odo_t, odo_yaw, *, span: int = 15,
                     min_speed: float = 0.4, max_turn_deg: float = 5.0) -> dict[str, float]:
    """Compare a heading series with the GPS course over ground on straight stretches.

    Course from fixes ``span`` apart (15 fixes: 6 s, 2-6 m at the Husky's speeds, so a fix error of
    ~1 m gives ~10-25° of course noise); kept where the robot moved at least ``min_speed`` m/s on
    average and the odometry yaw changed less than ``max_turn_deg`` over the stretch.
    """
    if len(fix_t) <= span:
        return {"n": 0}
    de, dn = east[span:] - east[:-span], north[span:] - north[:-span]
    ta, tb = fix_t[:-span], fix_t[span:]
    dist = np.hypot(de, dn)
    turn = np.abs(np.interp(tb, odo_t, odo_yaw) - np.interp(ta, odo_t, odo_yaw))
    ok = (dist >= min_speed * (tb - ta)) & (np.rad2deg(turn) < max_turn_deg)
    course = np.rad2deg(np.arctan2(de, dn))[ok]
    tc = 0.5 * (ta + tb)[ok]
    h = _interp_angle_deg(tc, t, np.deg2rad(heading_deg))
    stats = _circular_stats_deg(course - h)
    stats["n"] = int(ok.sum())
    return stats


def course_scale_fit(t, heading_deg, fix_t, east, north, odo_t, odo_yaw, *, span: int = 15,
                     min_speed: float = 0.4, max_turn_deg: float = 5.0,
                     scales=np.linspace(0.8, 1.3, 251), bootstrap: int = 0, block_s: float = 30.0,
                     seed: int = 0) -> dict[str, Any]:
    """Which scale of a heading's *changes* fits the GPS course best: h_s = h0 + s (h - h0).

    Same straight-stretch selection as ``gps_course_check``; the constant offset is removed at
    each trial scale; returns the best scale, the offset and the RMS about it (deg).  With
    ``bootstrap`` > 0, also a 95 % interval of the scale from a block bootstrap (blocks of
    ``block_s`` seconds: neighbouring course samples share fixes and are not independent).
    """
    de, dn = east[span:] - east[:-span], north[span:] - north[:-span]
    ta, tb = fix_t[:-span], fix_t[span:]
    turn = np.abs(np.interp(tb, odo_t, odo_yaw) - np.interp(ta, odo_t, odo_yaw))
    ok = (np.hypot(de, dn) >= min_speed * (tb - ta)) & (np.rad2deg(turn) < max_turn_deg)
    course = np.arctan2(de, dn)[ok]
    tc = 0.5 * (ta + tb)[ok]
    h = np.unwrap(np.deg2rad(np.asarray(heading_deg, dtype=np.float64)))
    hc = np.interp(tc, t, h) - h[0]

    def best_of(idx):
        best = None
        for sc in scales:
            e = course[idx] - sc * hc[idx]
            off = np.angle(np.mean(np.exp(1j * e)))
            rms = float(np.sqrt(np.mean(np.angle(np.exp(1j * (e - off))) ** 2)))
            if best is None or rms < best[0]:
                best = (rms, float(sc), float(off))
        return best

    rms, scale, off = best_of(np.arange(len(tc)))
    out: dict[str, Any] = {"scale": round(scale, 3), "offset_deg": round(float(np.rad2deg(off)), 1),
                           "rms_deg": round(float(np.rad2deg(rms)), 2), "n": int(ok.sum())}
    if bootstrap > 0 and len(tc):
        rng = np.random.default_rng(seed)
        blocks = np.floor((tc - tc[0]) / block_s).astype(int)
        members = [np.flatnonzero(blocks == b) for b in np.unique(blocks)]
        draws = [best_of(np.concatenate([members[i] for i in rng.integers(0, len(members), len(members))]))[1]
                 for _ in range(bootstrap)]
        out["scale_ci95"] = [round(float(x), 3) for x in np.percentile(draws, [2.5, 97.5])]
    return out


def import_husky(source, *, wheel_separation: float = HUSKY_WHEEL_SEPARATION, dpp: float = HUSKY_DPP,
                 counter_modulus: int = COUNTER_MODULUS) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Convert the Husky bag; returns (drive columns, import report)."""
    source = Path(source)
    if not wheel_separation > 0.0:
        raise OdoCompassError(f"wheel separation must be positive, got {wheel_separation}")
    if not dpp > 0.0:
        raise OdoCompassError(f"--dpp must be positive, got {dpp}")
    raw = read_husky_bag(source)
    odo, imu, fix = raw["odom"], raw["imu"], raw["fix"]
    keep = np.concatenate([[True], np.diff(odo[:, 0]) > 0.0])
    odo = odo[keep]
    # Only the span the IMU covers (the reference must be interpolated, never extrapolated).
    odo = odo[(odo[:, 0] >= imu[0, 0]) & (odo[:, 0] <= imu[-1, 0])]
    if len(odo) < 2:
        raise OdoCompassError(f"{source}: odometry and IMU share fewer than two samples in time")
    refuse_unbridgeable(f"{source} ({HUSKY_TOPIC_ODOM})", odo[:, 0], odo[:, 1:3], odo[0, 0], odo[-1, 0], "odometry")
    refuse_unbridgeable(f"{source} ({HUSKY_TOPIC_IMU})", imu[:, 0], imu[:, 1:5], odo[0, 0], odo[-1, 0], "IMU orientation")
    t, v, omega = odo[:, 0], odo[:, 1], odo[:, 2]

    # Skid-steer: left/right wheel speeds from the controller's v and omega (CCW positive).
    v_left = v - omega * wheel_separation / 2.0
    v_right = v + omega * wheel_separation / 2.0
    d_left = cumulative_trapezoid(v_left, t)
    d_right = cumulative_trapezoid(v_right, t)

    # Reference: base_link yaw from the IMU, x = magnetic north, CCW -> heading clockwise from true north.
    decl = CAMBRIDGE_2015["declination_deg"]
    yaw = husky_imu_yaw(imu)
    yaw_t = np.interp(t, imu[:, 0], yaw)
    magnetic_deg = wrap_deg(-np.rad2deg(yaw_t))
    ref_deg = wrap_deg(magnetic_deg + decl)
    h = CAMBRIDGE_2015["horizontal_uT"]
    compass_x = h * np.cos(np.deg2rad(magnetic_deg))
    compass_y = h * np.sin(np.deg2rad(magnetic_deg))

    # Controller's own yaw (integrated omega), as heading, started at the reference.
    odo_yaw = cumulative_trapezoid(omega, t)
    odom_heading = wrap_deg(ref_deg[0] - np.rad2deg(odo_yaw))

    columns: dict[str, np.ndarray] = {
        "time_s": t - t[0],
        "left_pulses": pulses_from_distance(d_left, dpp, counter_modulus),
        "right_pulses": pulses_from_distance(d_right, dpp, counter_modulus),
        "compass_x": compass_x,
        "compass_y": compass_y,
        "ref_heading_deg": ref_deg,
    }
    report: dict[str, Any] = {
        "source": str(source),
        "kind": "husky",
        "time_origin_s": float(t[0]),
        "time_origin_note": "time_s = ROS header stamp (Unix s) - time_origin_s",
        "samples": int(len(t)),
        "duration_s": round(float(t[-1] - t[0]), 3),
        "time_base": f"{HUSKY_TOPIC_ODOM} header stamps (10 Hz)",
        "wheel_separation_m": wheel_separation,
        "wheel_separation_source": f"husky_description track {HUSKY_TRACK} m x husky_control "
                                   f"wheel_separation_multiplier {HUSKY_SEPARATION_MULTIPLIER}",
        "dpp_m": dpp,
        "counter_modulus": counter_modulus,
        "distance_m": round(float(0.5 * (d_left[-1] + d_right[-1])), 3),
        "reference": "IMU orientation (/imu/data) -> base_link yaw (mount yaw -90 deg, roll +90 deg); the IMU "
                     "world frame is x = magnetic north, z = up; ref = -yaw + declination",
        "compass": "DERIVED from the IMU orientation (H = WMM horizontal intensity), not a raw magnetometer",
        "declination_deg": decl,
        "geomagnetic_field_wmm2015": CAMBRIDGE_2015,
        "odometry_yaw_change_deg": round(float(-np.rad2deg(odo_yaw[-1])), 2),
        "imu_yaw_change_deg": round(float(-np.rad2deg(yaw_t[-1] - yaw_t[0])), 2),
    }
    # The IMU's own gyro (z rate of base_link), integrated: a third opinion on the turn angles.
    gyro_yaw = np.interp(t, imu[:, 0], cumulative_trapezoid(husky_gyro_yaw_rate(imu), imu[:, 0]))
    gyro_yaw -= gyro_yaw[0]
    i240 = int(np.searchsorted(t - t[0], 240.0))
    if i240 < len(t):
        report["heading_change_at_240s_deg"] = {
            "odometry": round(float(-np.rad2deg(odo_yaw[i240])), 1),
            "imu": round(float(-np.rad2deg(yaw_t[i240] - yaw_t[0])), 1),
            "imu_gyro_integral": round(float(-np.rad2deg(gyro_yaw[i240])), 1)}

    if len(fix):
        good = np.isfinite(fix[:, 1]) & np.isfinite(fix[:, 2]) & (fix[:, 4] >= 0)
        fx = fix[good]
        east, north = local_east_north(fx[:, 1], fx[:, 2], fx[0, 1], fx[0, 2])
        # Each fix at the odometry sample nearest in time (within 0.06 s: half an odometry period).
        idx = np.clip(np.searchsorted(t, fx[:, 0]), 1, len(t) - 1)
        idx = np.where(np.abs(t[idx - 1] - fx[:, 0]) < np.abs(t[idx] - fx[:, 0]), idx - 1, idx)
        near = np.abs(t[idx] - fx[:, 0]) <= 0.06
        fe, fn, fv = np.zeros(len(t)), np.zeros(len(t)), np.zeros(len(t), dtype=np.int64)
        fe[idx[near]], fn[idx[near]], fv[idx[near]] = east[near], north[near], 1
        columns.update({"fix_east_m": fe, "fix_north_m": fn, "fix_valid": fv})
        report["fixes"] = {"count": int(near.sum()), "origin_lat_deg": float(fx[0, 1]),
                           "origin_lon_deg": float(fx[0, 2])}
        report["gps_course_minus_ref"] = gps_course_check(t, ref_deg, fx[:, 0], east, north, t, odo_yaw)
        report["gps_course_minus_odometry_heading"] = gps_course_check(t, odom_heading, fx[:, 0], east, north, t,
                                                                       odo_yaw)
        gyro_heading = wrap_deg(ref_deg[0] - np.rad2deg(gyro_yaw))
        report["gps_course_scale_fit"] = {
            name: course_scale_fit(t, h_deg, fx[:, 0], east, north, t, odo_yaw)
            for name, h_deg in (("imu_reference", ref_deg), ("controller_odometry", odom_heading),
                                ("imu_gyro_integral", gyro_heading))}
    # Extra columns (read_drive ignores them): the controller's and the IMU gyro's yaw, from the same start.
    columns["odom_heading_deg"] = odom_heading
    columns["gyro_heading_deg"] = wrap_deg(ref_deg[0] - np.rad2deg(gyro_yaw))
    return columns, report


def husky_params(report: dict[str, Any]) -> dict[str, Any]:
    """Nominal parameter file for the Husky (rear-axle mode, T_R = the controller's separation)."""
    w = float(report["wheel_separation_m"])
    return {
        "sensor_axle": "rear",
        "P": 0.125,
        "B": HUSKY_WHEELBASE,
        "T_F": w,
        "T_R": w,
        "a": 1.0e-4,
        "dpp_left": report["dpp_m"],
        "dpp_right": report["dpp_m"],
        "counter_modulus": float(report["counter_modulus"]),
        "variation_deg": report["declination_deg"],
        "X0": 0.0,
        "Y0": 0.0,
        "rotation_deg": 0.0,
        "field_magnitude": CAMBRIDGE_2015["horizontal_uT"],
        "max_speed": 5.0,
        "report": {
            "import": report,
            "sources": {
                "T_R, T_F": "the controller's effective wheel separation (track x multiplier); "
                            "T_F unused (rear axle)",
                "B": "husky_description wheelbase",
                "variation_deg, field_magnitude": "WMM2015v2 at the first GPS fix and the bag's date "
                                                  "(the compass is derived with the same H)",
                "max_speed": "plausibility limit: the Husky's controller limits it to 1 m/s here (3 m/s max)",
            },
        },
    }
