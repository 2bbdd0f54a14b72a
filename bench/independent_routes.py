"""Routes and the driver of the independent simulator (bench/independent_sim.py): curvature on an
arc-length grid for urban, mixed and highway roads, grade profiles, and a speed controller with preview
and jerk limits.  Written with independent_sim.py, without reading the project's own simulator."""
from __future__ import annotations

import math

import numpy as np

DS = 0.5            # route grid, metres
DT_SIM = 0.02       # simulation step, s (50 Hz)
KMH = 1.0 / 3.6


# ----------------------------------------------------------------------------- helpers
def smooth_noise(rng, n, corr_samples):
    """Unit-variance Gaussian noise low-passed with a Gaussian kernel."""
    corr_samples = max(1.0, float(corr_samples))
    half = int(4 * corr_samples)
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / corr_samples) ** 2)
    w = rng.standard_normal(n + 2 * half)
    y = np.convolve(w, k, mode="valid")[:n]
    return y / np.sqrt(np.sum(k ** 2))


def raised_cosine(n):
    return 0.5 - 0.5 * np.cos(np.pi * (np.arange(n) + 0.5) / n)


class Route:
    """Curvature, speed target and stops on a DS-metre arc-length grid."""

    def __init__(self):
        self.kappa: list = []
        self.vmax: list = []
        self.stops: list = []       # (s, duration)

    @property
    def length(self):
        return sum(len(k) for k in self.kappa) * DS

    def straight(self, L, v):
        n = max(1, int(round(L / DS)))
        self.kappa.append(np.zeros(n))
        self.vmax.append(np.full(n, v))

    def turn(self, theta_deg, R, v, ramp_frac=0.6):
        """Heading change theta (deg, + = right) on radius R with raised-cosine
        curvature ramps (clothoid-like: curvature and yaw rate stay continuous)."""
        th = math.radians(abs(theta_deg))
        if th < 1e-6:
            return
        arc = th * R
        Lr = ramp_frac * arc
        La = arc - Lr
        nr = max(2, int(round(Lr / DS)))
        na = int(round(La / DS))
        prof = np.concatenate([raised_cosine(nr), np.ones(na), raised_cosine(nr)[::-1]])
        k = prof / (np.sum(prof) * DS) * th * math.copysign(1.0, theta_deg)
        self.kappa.append(k)
        self.vmax.append(np.full(len(k), v))

    def lane_change(self, h, L, v):
        """Lateral offset h (m, + = right) over L metres; no net heading change."""
        n = max(4, int(round(L / DS)))
        s = (np.arange(n) + 0.5) * DS
        Lq = n * DS
        k = h * 2 * np.pi / Lq ** 2 * np.sin(2 * np.pi * s / Lq)
        self.kappa.append(k)
        self.vmax.append(np.full(n, v))

    def stop(self, duration):
        self.stops.append((self.length, float(duration)))

    def arrays(self):
        return np.concatenate(self.kappa), np.concatenate(self.vmax)


def _junction_turn(rng, route, v_turn_cap):
    right = rng.random() < 0.5
    ang = 90.0 + rng.normal(0.0, 6.0)
    R = rng.uniform(6.5, 11.0) if right else rng.uniform(10.0, 18.0)   # right-hand traffic
    route.turn(ang if right else -ang, R, v_turn_cap, ramp_frac=rng.uniform(0.5, 0.9))


def _roundabout(rng, route, v):
    net = float(rng.choice([90.0, 0.0, 0.0, -90.0, 180.0]))
    alpha = rng.uniform(50.0, 65.0)
    circ = 2 * alpha - net                                 # counter-clockwise circulation
    route.turn(alpha, rng.uniform(15.0, 25.0), v, ramp_frac=0.8)
    route.turn(-circ, rng.uniform(12.0, 22.0), v, ramp_frac=0.3)
    route.turn(alpha, rng.uniform(15.0, 25.0), v, ramp_frac=0.8)


def build_urban(rng, total_len):
    r = Route()
    r.stop(rng.uniform(3.0, 8.0))                         # parked at the start
    while r.length < total_len:
        v = rng.choice([30.0, 40.0, 50.0, 50.0]) * KMH * rng.uniform(0.9, 1.05)
        block = rng.uniform(60.0, 250.0)
        if rng.random() < 0.2:                            # a bend in the street
            r.straight(block / 2, v)
            r.turn(rng.choice([-1, 1]) * rng.uniform(5.0, 25.0), rng.uniform(40.0, 150.0), v)
            r.straight(block / 2, v)
        else:
            r.straight(block, v)
        if rng.random() < 0.35:                           # lights / stop sign
            r.stop(rng.uniform(2.0, 40.0) if rng.random() < 0.8 else rng.uniform(1.0, 3.0))
        u = rng.random()
        if u < 0.5:
            _junction_turn(rng, r, 25 * KMH)
        elif u < 0.56:
            _roundabout(rng, r, 30 * KMH)
    return r


def build_mixed(rng, total_len):
    r = build_urban(rng, rng.uniform(1500.0, 3000.0))
    while r.length < total_len:
        v = rng.uniform(75.0, 90.0) * KMH
        r.straight(rng.uniform(200.0, 1500.0), v)
        u = rng.random()
        if u < 0.12:                                      # a village
            vv = 50 * KMH * rng.uniform(0.9, 1.05)
            r.straight(rng.uniform(200.0, 450.0), vv)
            if rng.random() < 0.3:
                r.stop(rng.uniform(2.0, 30.0))
            if rng.random() < 0.4:
                _junction_turn(rng, r, 25 * KMH)
            r.straight(rng.uniform(200.0, 450.0), vv)
        elif u < 0.20:
            _roundabout(rng, r, 35 * KMH)
        elif u < 0.28:                                    # junction with a side road
            if rng.random() < 0.5:
                r.stop(rng.uniform(2.0, 20.0))
            _junction_turn(rng, r, 30 * KMH)
        else:                                             # rural curve
            r.turn(rng.choice([-1, 1]) * rng.uniform(10.0, 90.0), rng.uniform(120.0, 800.0), v,
                   ramp_frac=rng.uniform(0.3, 0.8))
    return r


def build_highway(rng, total_len):
    r = Route()
    r.stop(rng.uniform(3.0, 8.0))
    v = 50 * KMH
    r.straight(rng.uniform(200.0, 500.0), v)
    if rng.random() < 0.5:
        r.stop(rng.uniform(2.0, 20.0))
    _junction_turn(rng, r, 25 * KMH)
    r.straight(rng.uniform(200.0, 400.0), v)
    r.turn(rng.choice([-1, 1]) * rng.uniform(90.0, 270.0), rng.uniform(50.0, 90.0),
           60 * KMH, ramp_frac=0.5)                       # on-ramp
    r.straight(300.0, 100 * KMH)
    r.lane_change(-3.5, 100.0, 100 * KMH)
    while r.length < total_len:
        v = rng.uniform(100.0, 130.0) * KMH
        if rng.random() < 0.06:
            v = rng.uniform(60.0, 85.0) * KMH             # congestion / works
        L = rng.uniform(500.0, 3000.0)
        done = 0.0
        while done < L:                                   # lane changes on the straights
            piece = rng.uniform(400.0, 2500.0)
            r.straight(min(piece, L - done) + 1.0, v)
            done += piece
            if done < L and rng.random() < 0.7:
                Llc = v * rng.uniform(3.5, 6.0)
                r.lane_change(rng.choice([-1, 1]) * 3.6, Llc, v)
                done += Llc
        r.turn(rng.choice([-1, 1]) * rng.uniform(5.0, 40.0), rng.uniform(800.0, 4000.0), v,
               ramp_frac=rng.uniform(0.3, 0.7))
    return r


def grade_profile(rng, n, gmax):
    """Piecewise-constant grades joined by smooth vertical curves."""
    g = np.zeros(n)
    if gmax <= 0:
        return g
    i = 0
    pieces = []
    while i < n:
        L = int(rng.uniform(150.0, 800.0) / DS)
        nxt = 0.0 if rng.random() < 0.2 else rng.uniform(-gmax, gmax)
        pieces.append((i, min(n, i + L), nxt))
        i += L
    for a, b, val in pieces:
        g[a:b] = val
    # vertical curves: smooth with a ~60-m kernel
    return _gauss_smooth(g, 60.0 / DS)


def _gauss_smooth(x, sig):
    half = int(4 * sig)
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sig) ** 2)
    k /= k.sum()
    xp = np.concatenate([np.full(half, x[0]), x, np.full(half, x[-1])])
    return np.convolve(xp, k, mode="valid")


# ----------------------------------------------------------------------------- driver
def drive_profile(rng, kappa, vmax_seg, stops, duration, a_lat):
    """Speed controller with preview: comfortable braking for curves and stops,
    jerk-limited acceleration.  Returns 50 Hz arrays t, s, v, acc."""
    n = len(kappa)
    vlim = np.minimum(vmax_seg, np.sqrt(a_lat / np.maximum(np.abs(kappa), 1e-9)))
    vlim = _gauss_smooth(vlim, 2.0 / DS)
    vlim = np.minimum(vlim, np.sqrt(a_lat / np.maximum(np.abs(kappa), 1e-9)))
    vlim *= 1.0 + 0.04 * smooth_noise(rng, n, 150.0 / DS)      # driver's own variation
    b_plan = rng.uniform(1.2, 2.0)
    a_acc = rng.uniform(1.4, 2.4)
    jerk = rng.uniform(1.5, 3.0)
    kv = 1.2
    nsteps = int(round(duration / DT_SIM)) + 1
    t = np.arange(nsteps) * DT_SIM
    S = np.zeros(nsteps); V = np.zeros(nsteps); A = np.zeros(nsteps)
    s = v = a = 0.0
    stop_i = 0
    hold_until = None
    for k in range(nsteps):
        S[k], V[k], A[k] = s, v, a
        tk = t[k]
        if hold_until is not None:
            if tk < hold_until:
                continue
            hold_until = None
            stop_i += 1
        i0 = int(s / DS)
        look = int((v * v / (2 * b_plan) + 40.0) / DS) + 2
        seg = vlim[i0:i0 + look]
        if len(seg) == 0:
            raise RuntimeError("route too short for the drive duration")
        lag = 0.8 * v                                      # anticipate the controller's lag
        dist = np.maximum(i0 * DS + np.arange(len(seg)) * DS - s - lag, 0.0)
        vd = float(np.min(np.sqrt(seg ** 2 + 2 * b_plan * dist)))
        if stop_i < len(stops):
            s_stop, dur = stops[stop_i]
            d = s_stop - s
            if d <= 0.4 and v < 0.08:
                # at the stop line: stand still for the stop's duration
                v, a = 0.0, 0.0
                hold_until = tk + dur
                continue
            if d < 2.5 and v > 0.0:
                # final metres: the deceleration that ends exactly at the line
                a = max(-v * v / (2 * max(d - 0.1, 0.05)), -4.5)
                v = max(v + a * DT_SIM, 0.0)
                if v < 0.08:
                    v = 0.0 if d < 0.4 else 0.1
                s += v * DT_SIM
                continue
            vd = min(vd, math.sqrt(2 * b_plan * max(d - 0.5 - lag, 0.0)) + 0.3)
        acc_cap = a_acc * max(0.25, 1.0 - v / 45.0)
        a_cmd = float(np.clip(kv * (vd - v), -4.5, acc_cap))
        a += float(np.clip(a_cmd - a, -jerk * DT_SIM * 2, jerk * DT_SIM))
        v = max(v + a * DT_SIM, 0.0)
        if v == 0.0 and a < 0:
            a = 0.0
        s += v * DT_SIM
    return t, S, V, A
