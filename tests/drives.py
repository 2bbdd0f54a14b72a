"""Small deterministic drives built from the seed model itself (independent of the simulator).

A drive is a list of segments (distance m, path curvature 1/m (right turn > 0), speed m/s).
Wheel distances invert US 4,788,645 eq. (8) with eq. (14): dD = dpsi T_E(c) (1 + a V^2), where
c = dD/AD is found by fixed-point iteration; left = AD + dD/2, right = AD - dD/2.
"""

import math

import numpy as np

from oracle import effective_track


def seed_model_drive(segments, params, dt=0.1, heading0=0.0, field=20.0, compass_noise_deg=0.0, seed=0):
    p = params
    rng = np.random.default_rng(seed)
    t, head, dl, dr = [0.0], [heading0], [0.0], [0.0]
    psi = heading0
    for length, kappa, speed in segments:
        n = max(1, int(round(length / (speed * dt))))
        ad = length / n
        for _ in range(n):
            dpsi = kappa * ad
            if p["sensor_axle"] == "front":
                c = 0.0
                for _ in range(30):
                    dD = dpsi * effective_track(c, p["P"], p["B"], p["T_F"], p["curvature_clip"]) * (1 + p["a"] * speed**2)
                    c = dD / ad
            else:
                dD = dpsi * p["T_R"] * (1 + p["a"] * speed**2)
            psi += dpsi
            t.append(t[-1] + dt)
            head.append(psi)
            dl.append(dl[-1] + ad + dD / 2)
            dr.append(dr[-1] + ad - dD / 2)
    t, head = np.array(t), np.array(head)
    left = np.floor(np.array(dl) / p["dpp_left"])
    right = np.floor(np.array(dr) / p["dpp_right"])
    noise = np.deg2rad(compass_noise_deg) * rng.standard_normal(len(t))
    magnetic = head + noise - math.radians(p["variation_deg"])
    cx = field * np.cos(magnetic) + p["X0"]
    cy = field * np.sin(magnetic) + p["Y0"]
    wrapped = (head + np.pi) % (2 * np.pi) - np.pi
    return dict(time_s=t, left_pulses=left % p["counter_modulus"], right_pulses=right % p["counter_modulus"],
                compass_x=cx, compass_y=cy, true_heading=wrapped)


def rear_axle_columns(t, rate, speed, dpp, track, field, start_pulses, modulus=65536):
    """Log columns of a rear-axle drive (dD = dpsi T_R) from sample times t (s) and yaw rate (rad/s):
    exact pulse counts from ``start_pulses`` wrapping at ``modulus``, a clean compass of ``field``
    and the true heading as the reference."""
    dts = np.diff(t, prepend=t[0])
    dpsi = rate * dts
    psi = np.cumsum(dpsi)
    ad = speed * dts
    dD = dpsi * track
    left = start_pulses[0] + np.floor(np.cumsum(ad + dD / 2) / dpp)
    right = start_pulses[1] + np.floor(np.cumsum(ad - dD / 2) / dpp)
    return {
        "time_s": t,
        "left_pulses": (left % modulus).astype(np.int64),
        "right_pulses": (right % modulus).astype(np.int64),
        "compass_x": field * np.cos(psi),
        "compass_y": field * np.sin(psi),
        "ref_heading_deg": np.rad2deg(psi),
    }


def city_blocks(n_blocks=6, block=120.0, speed=10.0, radius=15.0, sign=1.0):
    """Straights joined by 90-degree turns, alternating right and left."""
    segs = []
    for i in range(n_blocks):
        segs.append((block, 0.0, speed))
        s = sign if i % 2 == 0 else -sign
        segs.append((math.pi / 2 * radius, s / radius, speed * 0.7))
    segs.append((block, 0.0, speed))
    return segs


def synthetic_columns(n=120, dt=0.1, speed=10.0, turn_rate=0.15, start_pulses=(65400, 65000), dpp=0.02,
                      track=1.55, field=40.0, seed=0):
    """A small drive: straight, a right turn, straight; counters start near the wrap and wrap at 2**16.

    Rear-axle geometry (dD = dpsi T_R), exact pulse counts, uneven time steps.
    """
    rng = np.random.default_rng(seed)
    steps = dt * (1.0 + 0.2 * rng.uniform(-1.0, 1.0, n))
    t = np.concatenate([[0.0], np.cumsum(steps[1:])]) + 1000.0
    rate = np.where((np.arange(n) > n // 4) & (np.arange(n) < n // 2), turn_rate, 0.0)
    return rear_axle_columns(t, rate, speed, dpp, track, field, start_pulses, 65536)


def assert_same(a, b, name=""):
    """a and b equal to the bit: same shape, NaN where NaN, and the sign of every zero."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, name
    assert np.array_equal(a, b, equal_nan=True), name
    # bit-exact for floats (array_equal treats -0.0 == 0.0)
    if a.dtype.kind == "f" and b.dtype.kind == "f":
        assert np.array_equal(np.signbit(a), np.signbit(b)), name
