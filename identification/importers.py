"""Converters from the two real logs in ``../shared/data/real/`` to the drive schema (SPEC §4).

``odocompass import comma2k19 SEGMENT_DIR --out DRIVE`` and ``odocompass import husky BAG --out DRIVE``
write the drive and, beside it, ``<DRIVE stem>.params.json``: a parameter file for that vehicle
whose ``report.import`` object records every conversion choice and the sanity checks.  The
choices, and the evidence for them, are written up in docs/real-data.md.

comma2k19 (Toyota RAV4, 60 s of highway, one public example segment)
    * time base: the magnetometer's own time stamps (~10 Hz), restricted to the span that the
      wheel speeds and the pose cover; ``time_s`` is seconds since the first sample.
    * pulses: the wheel speeds of one axle pair (``axle='front'`` -> FL/FR, default, or
      ``'rear'`` -> RL/RR; ~83 Hz, m/s) integrated (trapezoid) into distance, sampled at the
      time base, quantised to ``dpp`` m per pulse (default 0.02 m, floor) and wrapped at
      ``counter_modulus`` (65536).  The front pair is the default because it is the better
      balanced one on this segment (see docs/real-data.md); ``sensor_axle`` follows the choice.
    * compass: the calibrated magnetometer (µT, three axes).  The comma2k19 README gives the IMU
      axes as [forward, right, down]; the gyro agrees with the pose rotation in exactly those
      axes, and the magnetometer's x agrees too, but its z responds to the pitch steps of the
      road with the opposite sign, so z is taken as *up* (``COMMA_MAG_AXES``).  The vector is
      levelled with the pose's roll and pitch only (never its yaw, which would leak the
      reference heading into the compass); compass_x = levelled forward component,
      compass_y = levelled *left* component, so atan2(y, x) is the magnetic heading (SPEC §1).
    * reference: the heading of the camera's forward axis from ``global_pose/frame_orientations``
      (Hamilton quaternion [w, x, y, z]; as a rotation matrix it maps camera [forward, right,
      down] axes into ECEF, checked: its third axis points down, tilted only by the road's pitch), in the
      local ENU frame at each pose position, clockwise from true north.  The heading of the
      ECEF velocity is written too (extra column ``vel_heading_deg``) as a check.
    * the recording has no accelerometer file, so the pose's roll/pitch are the only tilt source.

Husky (Clearpath Husky, robot_localization test1.bag, 395 s outdoors)
    * time base: the controller's odometry messages (10 Hz, header stamps); ``time_s`` from 0.
    * pulses: left/right wheel speeds v -/+ omega W/2 from the controller's (v, omega), with W the
      controller's effective wheel separation (``HUSKY_WHEEL_SEPARATION``: husky_description track
      0.5708 m x husky_control ``wheel_separation_multiplier`` 1.875 = 1.0703 m, the values of
      the Husky packages of spring 2015; with T_R = W the estimator reproduces the controller's
      own yaw whatever W is, so W sets the meaning of T_R, not the result), integrated and
      quantised at ``dpp`` (default 0.001 m per pulse) and wrapped at ``counter_modulus``.
    * reference: yaw of base_link from the IMU orientation (``/imu/data``) through the static
      mounting of the robot_localization test launch file (base_link -> imu_link: yaw -90°,
      roll +90°).  The IMU's world frame is x = *magnetic north*, z = up (yaw counter-clockwise
      from magnetic north), not ENU: the GPS course over ground agrees with heading = -yaw +
      declination to within ~10°, while the ENU reading (90° - yaw) is ~100° off.  So
      ref_heading_deg = wrap(-yaw + declination), declination -14.78° (WMM2015, Cambridge MA,
      May 2015).
    * compass: **derived, not a raw magnetometer**: compass_x/y = H (cos, sin) of the IMU's
      magnetic heading -yaw, H = 20.09 µT (WMM horizontal intensity), so the compass agrees with
      the reference by construction and is there to start the odometer mode and to exercise
      the compass paths; compass-mode figures on this drive are meaningless and not reported.
    * fixes: ``/fix`` GPS (2.5 Hz) in metres east/north of the first fix, at the odometry sample
      nearest to each fix (within 0.06 s), ``fix_valid`` = 1 there, for the Kalman mode.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .errors import OdoCompassError

# --- constants, each with its source -------------------------------------------------------------

COUNTER_MODULUS = 65536
"""Pulse counters of the imported drives wrap at 2**16, as the simulator's and jaxmodel's default."""

COMMA_DPP = 0.02
"""m per pulse for the integrated comma2k19 wheel speeds (a typical ABS-ring resolution, SPEC §2)."""

COMMA_MAG_AXES = np.diag([1.0, 1.0, -1.0])
"""Maps the comma2k19 magnetometer vector to the camera's [forward, right, down] axes (z flipped:
the README's [forward, right, down] holds for x and y, the data show z pointing up)."""

RAV4 = {
    # Toyota RAV4 XA40 (2016-2018, the comma2k19 RAV4 of 2018), manufacturer data as published:
    "B": 2.66,      # wheel base 2,660 mm
    "T_F": 1.57,    # front tread ~1,570 mm
    "T_R": 1.57,    # rear tread ~1,570 mm
}

SF_2018 = {
    # WMM2015v2 at 37.721 N, 122.472 W, 30 m, 2018.585 (the comma2k19 segment, 2018-08-02):
    "declination_deg": 13.50, "inclination_deg": 61.12, "horizontal_uT": 23.24, "vertical_uT": 42.14,
}

HUSKY_TRACK = 0.5708
"""m, husky_description/urdf/husky.urdf.xacro ``track`` (2015)."""
HUSKY_SEPARATION_MULTIPLIER = 1.875
"""husky_control/config/control.yaml ``wheel_separation_multiplier`` (2015 - the skid-steer correction)."""
HUSKY_WHEEL_SEPARATION = HUSKY_TRACK * HUSKY_SEPARATION_MULTIPLIER
HUSKY_WHEELBASE = 0.512
"""m, husky_description ``wheelbase``."""
HUSKY_DPP = 0.001
"""m per pulse for the Husky (its encoders are far finer; 1 mm keeps quantization well below the
~5 cm travelled per 10 Hz sample)."""

CAMBRIDGE_2015 = {
    # WMM2015v2 at 42.3758 N, 71.1474 W, 7 m, 2015.386 (test1.bag, 2015-05-21):
    "declination_deg": -14.78, "inclination_deg": 67.38, "horizontal_uT": 20.09, "vertical_uT": 48.22,
}
HUSKY_IMU_MOUNT_YPR = (-math.pi / 2, 0.0, math.pi / 2)
"""base_link -> imu_link static transform (yaw, pitch, roll) of robot_localization's
test_ekf_localization_node_bag1 launch file, the launch file recorded with test1.bag."""

HUSKY_TOPIC_ODOM = "/husky_velocity_controller/odom"
HUSKY_TOPIC_IMU = "/imu/data"
HUSKY_TOPIC_FIX = "/fix"


# --- small geometry helpers ----------------------------------------------------------------------


def wrap_deg(a):
    """Degrees wrapped to (-180, 180]."""
    a = np.asarray(a, dtype=np.float64)
    w = np.mod(a + 180.0, 360.0) - 180.0
    return np.where(w == -180.0, 180.0, w)


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of Hamilton quaternions (N, 4) in [w, x, y, z] order (normalised here)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ecef_to_geodetic(xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """WGS-84 latitude, longitude (rad) and height (m) of ECEF points (N, 3), by fixed-point iteration."""
    xyz = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
    a, f = 6378137.0, 1.0 / 298.257223563
    e2 = f * (2.0 - f)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - e2))
    h = np.zeros_like(lat)
    for _ in range(8):
        n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - e2 * n / (n + h)))
    return lat, lon, h


def enu_from_ecef(lat, lon) -> np.ndarray:
    """Rotation matrices (N, 3, 3) taking ECEF vectors to local east, north, up."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    return np.stack([np.stack([-so, co, z], -1),
                     np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


def attitude_from_enu(axes_enu) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(heading, pitch, roll) in rad of bodies whose [forward, right, down] axes in ENU are the
    columns of ``axes_enu`` (N, 3, 3).  Heading clockwise from north; pitch nose-up positive;
    roll right-side-down positive (the ZYX Euler angles of the body in north-east-down)."""
    fwd = axes_enu[:, :, 0]
    right_up = axes_enu[:, 2, 1]
    down_up = axes_enu[:, 2, 2]
    heading = np.arctan2(fwd[:, 0], fwd[:, 1])
    pitch = np.arcsin(np.clip(fwd[:, 2], -1.0, 1.0))
    roll = np.arctan2(-right_up, -down_up)
    return heading, pitch, roll


def level(vectors_frd, pitch, roll) -> np.ndarray:
    """Body [forward, right, down] vectors (N, 3) expressed in the yaw-aligned level frame
    [forward, right, down]: v_level = R_y(pitch) R_x(roll) v_body (ZYX Euler, NED)."""
    v = np.asarray(vectors_frd, dtype=np.float64)
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    # R_x(roll): y' = cr y - sr z, z' = sr y + cr z; then R_y(pitch): x'' = cp x + sp z', z'' = -sp x + cp z'
    y1 = cr * y - sr * z
    z1 = sr * y + cr * z
    return np.stack([cp * x + sp * z1, y1, -sp * x + cp * z1], -1)


def pulses_from_distance(distance_m, dpp, modulus=COUNTER_MODULUS) -> np.ndarray:
    """Cumulative distance (m, from 0, may decrease when reversing) -> wrapped integer counter (int64)."""
    counts = np.floor(np.asarray(distance_m, dtype=np.float64) / dpp + 1e-9)
    return np.mod(counts, modulus).astype(np.int64)


def cumulative_trapezoid(values, t) -> np.ndarray:
    """Integral of ``values`` over ``t`` from t[0] (trapezoid), same length as t."""
    values = np.asarray(values, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    inc = 0.5 * (values[1:] + values[:-1]) * np.diff(t)
    return np.concatenate([[0.0], np.cumsum(inc)])


def _interp_angle_deg(t_out, t_in, angle_rad) -> np.ndarray:
    """Linear interpolation of an angle (rad) via unwrapping; returns wrapped degrees."""
    return wrap_deg(np.rad2deg(np.interp(t_out, t_in, np.unwrap(angle_rad))))


def _circular_stats_deg(diff_deg) -> dict[str, float]:
    d = wrap_deg(np.asarray(diff_deg, dtype=np.float64))
    d = d[np.isfinite(d)]
    mean = float(np.rad2deg(np.angle(np.mean(np.exp(1j * np.deg2rad(d))))))
    return {"mean_deg": round(mean, 3), "rms_deg": round(float(np.sqrt(np.mean(d ** 2))), 3),
            "max_abs_deg": round(float(np.max(np.abs(d))), 3),
            "std_about_mean_deg": round(float(np.std(wrap_deg(d - mean))), 3)}


MAX_GAP_S = 1.0
"""Longest time gap the importers bridge in wheel speeds, odometry, pose or IMU (integrating a
speed or interpolating a heading across a longer one would invent the drive)."""


def refuse_unbridgeable(where, t, values, lo: float, hi: float, what: str, max_gap: float = MAX_GAP_S) -> None:
    """Refuse (one line naming ``where``, the row and the time) NaN/inf in ``values`` and gaps longer
    than ``max_gap`` seconds in ``t`` within [lo, hi], the span the import uses."""
    t = np.asarray(t, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64).reshape(len(t), -1)
    inside = (t >= lo) & (t <= hi)
    bad = np.flatnonzero(inside & ~np.all(np.isfinite(v), axis=1))
    if bad.size:
        raise OdoCompassError(f"{where}: {bad.size} {what} samples are NaN or infinite (first at row {bad[0] + 1}, "
                              f"t = {t[bad[0]]:.3f} s); the importer cannot bridge them")
    ti = t[inside]
    if ti.size >= 2:
        gaps = np.diff(ti)
        j = int(np.argmax(gaps))
        if gaps[j] > max_gap:
            raise OdoCompassError(f"{where}: {what} has a gap of {gaps[j]:.3f} s (t = {ti[j]:.3f} to {ti[j + 1]:.3f} s), "
                                  f"longer than the {max_gap:g} s the importer bridges")


# --- comma2k19 -----------------------------------------------------------------------------------

COMMA_FILES = {
    "wheel_t": "processed_log/CAN/wheel_speed/t",
    "wheel_v": "processed_log/CAN/wheel_speed/value",
    "mag_t": "processed_log/IMU/magnetometer/t",
    "mag_v": "processed_log/IMU/magnetometer/value",
    "pose_t": "global_pose/frame_times",
    "pose_pos": "global_pose/frame_positions",
    "pose_vel": "global_pose/frame_velocities",
    "pose_q": "global_pose/frame_orientations",
}
COMMA_OPTIONAL = {"speed_t": "processed_log/CAN/speed/t", "speed_v": "processed_log/CAN/speed/value"}


def _load_comma(source: Path) -> dict[str, np.ndarray]:
    if not source.is_dir():
        raise OdoCompassError(f"{source}: not a comma2k19 segment folder (expected processed_log/ and global_pose/)")
    arrays = {}
    for key, rel in {**COMMA_FILES, **COMMA_OPTIONAL}.items():
        path = source / rel
        if not path.is_file():
            if key in COMMA_OPTIONAL:
                continue
            raise OdoCompassError(f"{path}: missing comma2k19 file '{rel}'")
        try:
            with open(path, "rb") as fh:
                arrays[key] = np.load(fh, allow_pickle=False)
        except Exception as exc:  # a corrupt array file: one line
            raise OdoCompassError(f"{path}: cannot read as a NumPy array: {' '.join(str(exc).split())}") from None
    shapes = {"wheel_v": 4, "mag_v": 3, "pose_pos": 3, "pose_vel": 3, "pose_q": 4}
    for key, width in shapes.items():
        a = arrays[key]
        if a.ndim != 2 or a.shape[1] != width:
            raise OdoCompassError(f"{source / COMMA_FILES[key]}: expected an (N, {width}) array, got shape {a.shape}")
    for tk, vk in (("wheel_t", "wheel_v"), ("mag_t", "mag_v"), ("pose_t", "pose_q"), ("pose_t", "pose_pos"),
                   ("pose_t", "pose_vel")):
        if len(arrays[tk]) != len(arrays[vk]):
            raise OdoCompassError(f"{source / COMMA_FILES[vk]}: {len(arrays[vk])} rows but "
                                  f"{COMMA_FILES[tk]} has {len(arrays[tk])}")
    for tk in ("wheel_t", "mag_t", "pose_t"):
        t = arrays[tk]
        if len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0.0):
            raise OdoCompassError(f"{source / COMMA_FILES[tk]}: time stamps must be finite and non-decreasing")
    return arrays


def comma_pose(arrays) -> dict[str, np.ndarray]:
    """Per pose sample: heading, pitch, roll of the camera (rad), velocity heading (rad), speed (m/s)."""
    lat, lon, _h = ecef_to_geodetic(arrays["pose_pos"])
    r_enu = enu_from_ecef(lat, lon)
    axes_enu = r_enu @ quat_to_matrix(arrays["pose_q"])
    heading, pitch, roll = attitude_from_enu(axes_enu)
    v_enu = np.einsum("nij,nj->ni", r_enu, arrays["pose_vel"])
    return {"t": arrays["pose_t"], "heading": heading, "pitch": pitch, "roll": roll,
            "vel_heading": np.arctan2(v_enu[:, 0], v_enu[:, 1]), "speed": np.linalg.norm(v_enu[:, :2], axis=1),
            "down_up": axes_enu[:, 2, 2], "lat": lat, "lon": lon}


def import_comma2k19(source, *, axle: str = "front", dpp: float = COMMA_DPP,
                     counter_modulus: int = COUNTER_MODULUS) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Convert a comma2k19 segment folder; returns (drive columns, import report)."""
    source = Path(source)
    if axle not in ("front", "rear"):
        raise OdoCompassError(f"--axle must be 'front' or 'rear', got {axle!r}")
    if not dpp > 0.0:
        raise OdoCompassError(f"--dpp must be positive, got {dpp}")
    arr = _load_comma(source)
    lo = max(arr["wheel_t"][0], arr["pose_t"][0])
    hi = min(arr["wheel_t"][-1], arr["pose_t"][-1])
    refuse_unbridgeable(source / COMMA_FILES["wheel_v"], arr["wheel_t"], arr["wheel_v"], lo, hi, "wheel speed")
    for key in ("pose_pos", "pose_vel", "pose_q"):
        refuse_unbridgeable(source / COMMA_FILES[key], arr["pose_t"], arr[key], lo, hi, "pose")
    pose = comma_pose(arr)

    # Time base: magnetometer samples inside the span of wheel speeds and pose.
    t_mag = arr["mag_t"]
    keep = (t_mag >= lo) & (t_mag <= hi) & np.all(np.isfinite(arr["mag_v"]), axis=1)
    keep &= np.concatenate([[True], np.diff(t_mag) > 0.0])  # drop a repeated time stamp
    if keep.sum() < 2:
        raise OdoCompassError(f"{source}: magnetometer, wheel speeds and pose share fewer than two samples in time")
    t = t_mag[keep]
    mag = arr["mag_v"][keep]

    # Wheel distances -> pulses.
    cols = (0, 1) if axle == "front" else (2, 3)
    t_w = arr["wheel_t"]
    order = np.argsort(t_w, kind="stable")
    t_w, v_w = t_w[order], arr["wheel_v"][order]
    d_left = np.interp(t, t_w, cumulative_trapezoid(v_w[:, cols[0]], t_w))
    d_right = np.interp(t, t_w, cumulative_trapezoid(v_w[:, cols[1]], t_w))
    d_left -= d_left[0]
    d_right -= d_right[0]

    # Pose at the time base.
    pitch = np.interp(t, pose["t"], pose["pitch"])
    roll = np.interp(t, pose["t"], pose["roll"])
    ref_deg = _interp_angle_deg(t, pose["t"], pose["heading"])
    vel_deg = _interp_angle_deg(t, pose["t"], pose["vel_heading"])

    # Magnetometer -> camera axes -> level frame -> compass (x forward, y left).
    m_frd = mag @ COMMA_MAG_AXES.T
    m_level = level(m_frd, pitch, roll)
    compass_x = m_level[:, 0]
    compass_y = -m_level[:, 1]

    columns = {
        "time_s": t - t[0],
        "left_pulses": pulses_from_distance(d_left, dpp, counter_modulus),
        "right_pulses": pulses_from_distance(d_right, dpp, counter_modulus),
        "compass_x": compass_x,
        "compass_y": compass_y,
        "ref_heading_deg": ref_deg,
        # extra columns (not in the schema; read_drive ignores them):
        "vel_heading_deg": vel_deg,
        "speed_mps": np.interp(t, pose["t"], pose["speed"]),
        "pitch_deg": np.rad2deg(pitch),
        "roll_deg": np.rad2deg(roll),
        "mag_down_uT": m_level[:, 2],
    }

    moving = columns["speed_mps"] > 2.0
    mag_heading = np.rad2deg(np.arctan2(compass_y, compass_x))
    report = {
        "source": str(source),
        "kind": "comma2k19",
        "time_origin_s": float(t[0]),
        "time_origin_note": "time_s = boot-clock seconds - time_origin_s",
        "samples": int(len(t)),
        "duration_s": round(float(t[-1] - t[0]), 3),
        "time_base": "magnetometer time stamps (~10 Hz) within the wheel-speed and pose span",
        "axle": axle,
        "wheels": ["FL", "FR"] if axle == "front" else ["RL", "RR"],
        "dpp_m": dpp,
        "counter_modulus": counter_modulus,
        "distance_left_m": round(float(d_left[-1]), 3),
        "distance_right_m": round(float(d_right[-1]), 3),
        "magnetometer_axes": "calibrated magnetometer taken as [forward, right, up] (z flipped against the "
                             "README's [forward, right, down]: see docs/real-data.md), levelled with the pose "
                             "roll and pitch; compass_x = level forward, compass_y = level left",
        "reference": "camera forward axis from global_pose/frame_orientations (ECEF), local ENU at each "
                     "pose position, clockwise from true north",
        "ref_minus_velocity_heading": _circular_stats_deg(ref_deg[moving] - vel_deg[moving]),
        "compass_magnetic_heading_minus_ref": _circular_stats_deg(mag_heading - ref_deg),
        "horizontal_field_mean_uT": round(float(np.mean(np.hypot(compass_x, compass_y))), 3),
        "vertical_field_mean_uT": round(float(np.mean(m_level[:, 2])), 3),
        "geomagnetic_field_wmm2015": SF_2018,
        "pose_down_axis_up_component_min": round(float(np.min(-pose["down_up"])), 5),
        "latitude_deg": round(float(np.rad2deg(pose["lat"][0])), 5),
        "longitude_deg": round(float(np.rad2deg(pose["lon"][0])), 5),
    }
    return columns, report


def comma2k19_params(report: dict[str, Any]) -> dict[str, Any]:
    """Parameter file for the comma2k19 RAV4 (flat SPEC §3 keys plus a ``report``)."""
    return {
        "sensor_axle": report["axle"],
        # P: unknown for this car and not identifiable on a straight highway: keep the default.
        "P": 0.125,
        "B": RAV4["B"],
        "T_F": RAV4["T_F"],
        "T_R": RAV4["T_R"],
        "a": 1.0e-4,
        "dpp_left": report["dpp_m"],
        "dpp_right": report["dpp_m"],
        "counter_modulus": float(report["counter_modulus"]),
        "variation_deg": SF_2018["declination_deg"],
        # X0/Y0: the phone's hard-iron residual cannot be separated from the heading on a drive
        # that holds one heading (docs/real-data.md); 0 = uncalibrated.
        "X0": 0.0,
        "Y0": 0.0,
        "rotation_deg": 0.0,
        # field_magnitude 0: learned on the drive (the uncalibrated car field is not the WMM one).
        "field_magnitude": 0.0,
        "report": {
            "import": report,
            "sources": {
                "B, T_F, T_R": "Toyota RAV4 XA40 (2016-2018) published dimensions: wheel base 2,660 mm, "
                               "tread ~1,570 mm front and rear (not measured on this car)",
                "variation_deg": "WMM2015v2 declination at the segment's position and date",
                "P, a": "defaults (not identifiable from a 60 s straight drive)",
            },
        },
    }


# --- Husky (ROS 1 bag): identification/import_husky.py ----------------------------------------

HUSKY_NAMES = ('_stamp', 'read_husky_bag', 'husky_imu_yaw', 'husky_gyro_yaw_rate', 'local_east_north', 'gps_course_check', 'course_scale_fit', 'import_husky', 'husky_params')


def __getattr__(name):  # the Husky importer lives in its own module; its names are still found here
    if name in HUSKY_NAMES:
        from . import import_husky as _husky

        return getattr(_husky, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# --- experiments helpers -------------------------------------------------------------------------


def split_drive(drive, fraction: float):
    """Split a Drive at ``fraction`` of its duration: (samples with t < t0 + f T, the rest).

    Both parts are complete drives (Inputs sliced, reference sliced, metadata updated); the
    second starts its counters and its compass afresh, as a new log would.
    """
    import jaxmodel

    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must be in (0, 1), got {fraction}")
    t = np.asarray(drive.inputs.time_s, dtype=np.float64)
    cut = t[0] + fraction * (t[-1] - t[0])
    k = int(np.searchsorted(t, cut, side="left"))
    if k < 2 or len(t) - k < 2:
        raise ValueError(f"fraction {fraction} leaves fewer than two samples on one side")
    parts = []
    for sl, label in ((slice(0, k), f"[0, {fraction:g})"), (slice(k, None), f"[{fraction:g}, 1]")):
        inputs = jaxmodel.Inputs(*(np.asarray(v)[sl] for v in drive.inputs))
        ref = None if drive.ref_heading is None else np.asarray(drive.ref_heading)[sl]
        meta = dict(drive.metadata)
        ts = np.asarray(inputs.time_s)
        meta.update(path=f"{drive.path}{label}", n_samples=int(len(ts)), duration_s=float(ts[-1] - ts[0]),
                    split=label)
        parts.append(dataclasses.replace(drive, inputs=inputs, ref_heading=ref, metadata=meta))
    return parts[0], parts[1]


def heading_rmse_deg(estimated_deg, ref_deg, skip_s: float = 0.0, time_s=None) -> float:
    """RMS of the wrapped heading error (degrees), optionally ignoring the first ``skip_s`` seconds."""
    e = wrap_deg(np.asarray(estimated_deg, dtype=np.float64) - np.asarray(ref_deg, dtype=np.float64))
    ok = np.isfinite(e)
    if time_s is not None and skip_s > 0.0:
        ts = np.asarray(time_s, dtype=np.float64)
        ok &= ts >= ts[0] + skip_s
    return float(np.sqrt(np.mean(e[ok] ** 2)))


# --- command line --------------------------------------------------------------------------------


def params_path_for(drive_path) -> Path:
    """``build/x.csv`` -> ``build/x.params.json``."""
    p = Path(drive_path)
    return p.with_name(p.stem + ".params.json")


def main(args) -> int:
    """``odocompass import``: outputs checked before the work (never the source), the drive and its
    parameter file written together atomically, both checked (SPEC §4, validate_params) first."""
    from jaxmodel.params import make_params, validate_params

    from . import console
    from .drive_log import drive_from_columns, write_drive
    from .outputs import check_drive_outputs, staged

    source = Path(args.source)
    out, ppath = check_drive_outputs(args.out, lambda p: [params_path_for(p)], inputs=[("the source", source)])
    dpp = getattr(args, "dpp", None)
    console.status(f"importing {args.kind} {source}")
    if args.kind == "comma2k19":
        columns, report = import_comma2k19(source, axle=getattr(args, "axle", None) or "front",
                                           dpp=COMMA_DPP if dpp is None else dpp)
        params = comma2k19_params(report)
    else:
        if getattr(args, "axle", None) not in (None, "rear"):
            raise OdoCompassError("the Husky import is rear-axle only (skid steer): drop --axle or use --axle rear")
        from .import_husky import husky_params, import_husky

        columns, report = import_husky(source, dpp=HUSKY_DPP if dpp is None else dpp)
        params = husky_params(report)
    drive = drive_from_columns(columns, source=str(out))  # the drive must pass the SPEC §4 checks
    flat = {k: v for k, v in params.items() if k != "report"}
    validate_params(make_params(flat))
    text = json.dumps(params, indent=2, allow_nan=False) + "\n"
    with staged([out, ppath]) as (tmp_drive, tmp_params):
        write_drive(tmp_drive, columns)
        tmp_params.write_text(text, encoding="utf-8")
    measured, expected = report.get("horizontal_field_mean_uT"), report.get("geomagnetic_field_wmm2015", {})
    if measured and expected.get("horizontal_uT"):
        from .diagnostics import FIELD_RATIO

        ratio = measured / expected["horizontal_uT"]
        if not FIELD_RATIO[0] <= ratio <= FIELD_RATIO[1]:
            console.warn(f"{source}: the magnetometer looks uncalibrated: measured horizontal field {measured:.1f} uT "
                         f"(mean) against {expected['horizontal_uT']:.1f} uT expected there (WMM, x{ratio:.2f}); "
                         f"headings from this compass will be off")
    console.info(f"imported {args.kind} {source}: {drive.n_samples} samples, "
                 f"{drive.metadata['duration_s']:.1f} s; wrote {out} and {ppath}")
    return 0


HUSKY_WIDE_TR_PRIOR = 0.2
"""Prior std of log T_R for the second Husky fit: a skid-steer's *effective* track is known only
roughly (the controller's own multiplier, 1.875, says so), unlike a car's datasheet track (5 %)."""


def _experiments_main(argv=None) -> int:
    """The real-data experiments moved to ``identification.real_data`` (issue 11); kept runnable here."""
    from .real_data import main

    return main(argv)


if __name__ == "__main__":
    sys.exit(_experiments_main())
