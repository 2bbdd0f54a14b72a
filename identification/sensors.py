"""Sensor error models of a dead-reckoning car: wheel pulse counters and a 2-axis magnetic compass.

Pure numpy, no imports from the project: the vehicle FMU bundles this file as it is.  Every
function works on scalars and on arrays, so the batch simulator (``identification.simulate``)
and a step-by-step vehicle model (``SensorModel.step``) share the same physics.

Conventions (SPEC §1): heading clockwise from true north (rad); x east, y north (m);
ΔD = D_L - D_R (a right turn makes ΔD > 0); compass components mounted so that for an ideal,
level sensor ``atan2(compass_y, compass_x)`` is the magnetic heading, and the estimator forms
H_C = atan2(Y - Y0, X - X0) + deviation(raw) - R + V (US 4,734,863 FIG. 8A).  The models here
are the inverse of that: they produce the raw components from which the estimator, given the
true parameters, recovers the true heading up to the sensor errors modelled below.

Error models
------------
* wheels: a slowly varying differential slip (an Ornstein-Uhlenbeck process over travelled
  distance, relative to the distance: an additive error on ΔD/AD) plus white noise on ΔD;
  pulse counting by ``floor(distance / true dpp)`` from a random phase and a random counter
  start value, wrapping at ``counter_modulus``; negative distances count down (reversing).
* compass: the earth field (horizontal ``B_h``, vertical ``B_z`` ≈ 2 B_h, i.e. a dip of ~63°)
  rotated into the vehicle frame with pitch and roll, so hills and body roll leak the vertical
  field into the horizontal components (dip error, magnitude change); localized anomalies
  (bridges, rail crossings, parked trucks, steel buildings) as Gaussian lobes fixed in space;
  short transients (passing trucks, trams); mounting rotation, deviation, hard-iron offsets and
  white noise per axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_FIELD_UT = 20.0
"""Horizontal earth field (µT) used when the parameters give none (field_magnitude <= 0)."""


def horizontal_field(field_magnitude):
    """The simulated horizontal field (µT) for a parameter ``field_magnitude``: itself when given (> 0), else
    DEFAULT_FIELD_UT (the estimator's reading of the same convention: ``jaxmodel.params.field_magnitude_given``)."""
    return field_magnitude if field_magnitude > 0 else DEFAULT_FIELD_UT


DIP_RATIO = 2.0
"""Vertical over horizontal field, tan(dip): 2.0 is a dip of 63.4°, as in central Europe / the US midwest."""
DEVIATION_TABLE_SIZE = 36

# Anomaly kinds: (|horizontal disturbance| µT range, road length affected m range, P(known to the map)).
ANOMALY_KINDS: dict[str, tuple[tuple[float, float], tuple[float, float], float]] = {
    "bridge": ((6.0, 15.0), (40.0, 150.0), 0.8),
    "rail": ((5.0, 15.0), (20.0, 50.0), 0.8),
    "truck": ((3.0, 10.0), (20.0, 35.0), 0.0),
    "building": ((3.0, 8.0), (40.0, 120.0), 0.3),
}
ANOMALY_KIND_NAMES = tuple(ANOMALY_KINDS)
ANOMALY_CUTOFF = 3.0
"""A lobe of radius r is evaluated out to ANOMALY_CUTOFF * r (exp(-9) ~ 1e-4 of its amplitude)."""
ANOMALY_FLAG_RADIUS = 1.6
"""A known anomaly flags the area within this many radii of its lobes (amplitude above ~8 %)."""


def wrap(angle):
    """Angle wrapped to (-pi, pi]."""
    a = np.mod(np.asarray(angle, dtype=np.float64) + math.pi, 2.0 * math.pi) - math.pi
    return np.where(a == -math.pi, math.pi, a)


# ----------------------------------------------------------------------------------------------
# Wheels
# ----------------------------------------------------------------------------------------------

def max_curvature(B, T_F):
    """Geometric maximum of ΔD/AD, where the inner square root of US 4,788,645 eq. (14) vanishes."""
    return 1.0 / math.sqrt((2.0 * B / T_F) ** 2 + 0.25)


def effective_track(c, P, B, T_F):
    """T_E(c; P, B, T_F) of US 4,788,645 eq. (14) (numpy copy of jaxmodel.track.effective_track, unclipped)."""
    c2 = np.square(np.asarray(c, dtype=np.float64))
    q = c2 / (1.0 - 0.25 * c2) * (2.0 * B / T_F) ** 2
    inner = np.sqrt(np.clip(1.0 - q, 0.0, None))
    return T_F * (P + (1.0 - P) * np.sqrt(0.5 + 0.5 * inner))


def differential_distance(d_heading, AD, dt, *, P, B, T_F, T_R, a, front=True, clip_fraction=0.97, iterations=30):
    """ΔD that makes the seed's wheel model give exactly ``d_heading`` over ``AD``: the inverse of eq. (8).

    ΔD = Δψ · T(c) · (1 + a V²) with V = |AD|/dt and, for front-axle sensors, T = T_E(c) of eq. (14)
    where c = ΔD/AD is solved by fixed-point iteration (a contraction: dT_E/dc is small below the
    clip).  Rear-axle sensors use T = T_R.  Returns (ΔD [m], c).
    """
    d_heading = np.asarray(d_heading, dtype=np.float64)
    AD = np.asarray(AD, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)
    speed = np.abs(AD) / np.where(dt > 0.0, dt, np.inf)
    gain = 1.0 + a * speed * speed
    moving = np.abs(AD) > 1e-12
    kappa = np.where(moving, d_heading / np.where(moving, AD, 1.0), 0.0)  # heading change per signed metre
    if not front:
        c = kappa * T_R * gain
        return c * AD, c
    c_lim = clip_fraction * max_curvature(B, T_F)
    c = np.clip(kappa * T_F * gain, -c_lim, c_lim)
    for _ in range(iterations):
        c_new = np.clip(kappa * effective_track(c, P, B, T_F) * gain, -c_lim, c_lim)
        if np.max(np.abs(c_new - c), initial=0.0) < 1e-15:
            c = c_new
            break
        c = c_new
    return c * AD, c


def ou_filter(steps, length, sigma, white, x0=0.0):
    """Ornstein-Uhlenbeck samples over irregular steps (distance or time), exact discretization.

    x_k = x_{k-1} e^{-s_k/L} + sigma sqrt(1 - e^{-2 s_k/L}) w_k, with w_k the given unit white
    noise; ``steps`` are |increments| (>= 0).  Returns (x, last x).
    """
    s = np.abs(np.asarray(steps, dtype=np.float64))
    decay = np.exp(-s / length)
    drive = (sigma * np.sqrt(1.0 - decay * decay) * np.asarray(white, dtype=np.float64)).tolist()
    decay = decay.tolist()
    out = [0.0] * len(decay)
    x = float(x0)
    for k in range(len(decay)):  # plain floats: ~0.2 µs per sample
        x = x * decay[k] + drive[k]
        out[k] = x
    return np.asarray(out, dtype=np.float64), x


@dataclass
class SlipModel:
    """Differential wheel slip: error on ΔD = eps(s) |AD| + white.

    eps is an OU process over travelled distance (``sigma_rel`` relative, correlation
    ``corr_m``): tyre deformation, road camber, lane wander of the wheels over an uneven surface.
    ``white_m`` is the standard deviation of an extra per-metre white error on ΔD (m per sqrt(m)).
    """

    sigma_rel: float = 1.5e-4
    corr_m: float = 2.0
    white_m: float = 1.0e-4

    def errors(self, AD, rng, state=0.0):
        """ΔD errors (m) for the signed per-sample distances AD; returns (errors, new state)."""
        AD = np.atleast_1d(np.asarray(AD, dtype=np.float64))
        n = AD.shape[0]
        eps, state = ou_filter(AD, self.corr_m, self.sigma_rel, rng.standard_normal(n), state)
        white = self.white_m * np.sqrt(np.abs(AD)) * rng.standard_normal(n)
        return eps * np.abs(AD) + white, state


def split_wheels(AD, dD):
    """Left/right distances from AD and ΔD = D_L - D_R (SPEC §1)."""
    return AD + 0.5 * dD, AD - 0.5 * dD


def count_pulses(distance_m, dpp_m, modulus=65536, offset_counts=0.0, phase=0.0):
    """Cumulative pulse counter reading for a cumulative (signed) wheel distance.

    counts = floor(distance / dpp + phase) + offset, wrapped into [0, modulus).  ``dpp_m`` is the
    TRUE distance per pulse of that wheel; ``phase`` in [0, 1) is where the first tooth sits.
    Returns int64.
    """
    n = np.floor(np.asarray(distance_m, dtype=np.float64) / dpp_m + phase) + np.floor(offset_counts)
    return np.mod(n, modulus).astype(np.int64)


# ----------------------------------------------------------------------------------------------
# Compass
# ----------------------------------------------------------------------------------------------

def earth_field_ned(horizontal=DEFAULT_FIELD_UT, vertical=None, variation_rad=0.0):
    """Earth field (north, east, down) in µT: horizontal part towards magnetic north (true bearing = variation)."""
    vertical = DIP_RATIO * horizontal if vertical is None else vertical
    return np.array([horizontal * math.cos(variation_rad), horizontal * math.sin(variation_rad), vertical])


def body_field(field_ned, heading, pitch=0.0, roll=0.0):
    """Field in the vehicle frame (forward, right, down) for yaw=heading, pitch (nose up +), roll (right down +).

    ``field_ned`` is (..., 3) or (3,).  ZYX Euler angles: m_body = Rx(roll)^T Ry(pitch)^T Rz(heading)^T m_ned.
    """
    f = np.asarray(field_ned, dtype=np.float64)
    n, e, d = f[..., 0], f[..., 1], f[..., 2]
    ch, sh = np.cos(heading), np.sin(heading)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    x1 = n * ch + e * sh
    y1 = -n * sh + e * ch
    x2 = x1 * cp - d * sp
    z2 = x1 * sp + d * cp
    y3 = y1 * cr + z2 * sr
    z3 = -y1 * sr + z2 * cr
    return x2, y3, z3


def deviation(raw, deviation_deg):
    """Deviation (rad) at raw angle ``raw`` (rad): periodic linear interpolation of the 36-entry table (FIG. 8A)."""
    table = np.asarray(deviation_deg, dtype=np.float64)
    u = np.mod(raw, 2.0 * math.pi) / math.radians(360.0 / DEVIATION_TABLE_SIZE)
    i = np.floor(u)
    w = u - i
    i0 = np.mod(i, DEVIATION_TABLE_SIZE).astype(np.int64)
    i1 = np.mod(i + 1, DEVIATION_TABLE_SIZE).astype(np.int64)
    return np.radians(table[i0] * (1.0 - w) + table[i1] * w)


def raw_angle_for(target, deviation_deg, iterations=20):
    """The raw angle A with A + deviation(A) = target (fixed point; the table's slope must stay below 1)."""
    raw = np.asarray(target, dtype=np.float64)
    for _ in range(iterations):
        raw = target - deviation(raw, deviation_deg)
    return raw


def compass_reading(heading, pitch=0.0, roll=0.0, *, disturbance_ned=None, horizontal=DEFAULT_FIELD_UT,
                    vertical=None, variation_deg=0.0, rotation_deg=0.0, X0=0.0, Y0=0.0, deviation_deg=None,
                    noise=None):
    """Raw 2-axis compass components (compass units, µT) for a vehicle at ``heading`` (true, rad).

    The field is the earth field plus ``disturbance_ned`` (..., 3) (anomalies, transients), rotated
    into the vehicle frame with pitch and roll (the vertical field leaks through both), then into
    the sensor: y is to the LEFT (so atan2(y, x) is the clockwise heading), the mounting rotation
    R turns the reading by +R, the deviation table by -deviation (the estimator adds it back),
    and the hard-iron offsets X0, Y0 and the white ``noise`` (..., 2) are added.
    """
    field = earth_field_ned(horizontal, vertical, math.radians(variation_deg))
    if disturbance_ned is not None:
        field = field + np.asarray(disturbance_ned, dtype=np.float64)
    fx, fy_right, _ = body_field(field, heading, pitch, roll)
    cx, cy = fx, -fy_right
    rot = math.radians(rotation_deg)
    if deviation_deg is not None and np.any(np.asarray(deviation_deg) != 0.0):
        # the clean reading's angle after mounting is psi_m + R; the raw angle A solves A + dev(A) = psi_m + R
        target = np.asarray(heading, dtype=np.float64) - math.radians(variation_deg) + rot
        rot = rot + (raw_angle_for(target, deviation_deg) - target)
    cr, sr = np.cos(rot), np.sin(rot)
    sx = cx * cr - cy * sr + X0
    sy = cx * sr + cy * cr + Y0
    if noise is not None:
        noise = np.asarray(noise, dtype=np.float64)
        sx = sx + noise[..., 0]
        sy = sy + noise[..., 1]
    return sx, sy


class AnomalyField:
    """Localized magnetic anomalies fixed in space: a set of Gaussian lobes v_k exp(-|p - c_k|^2 / r_k^2).

    Each anomaly (bridge, rail crossing, parked truck, steel building) is one lobe or a dipole-like
    pair of opposite lobes; ``vector`` is (north, east, down) in µT.  ``known`` marks the lobes the
    map knows (``unreliable`` flags the area around them).  With ``density_per_km2 > 0`` the plane
    is also tiled with procedurally generated anomalies (deterministic per tile and seed), for a
    vehicle model that drives anywhere (the FMU).
    """

    def __init__(self, centers=None, radius=None, vector=None, known=None, *, density_per_km2=0.0, seed=0,
                 tile_m=250.0, kinds=None):
        self.tile_m = float(tile_m)
        self.density_per_km2 = float(density_per_km2)
        self.seed = int(seed)
        self.kinds = tuple(kinds) if kinds is not None else ANOMALY_KIND_NAMES
        self._c = np.zeros((0, 2))
        self._r = np.zeros(0)
        self._v = np.zeros((0, 3))
        self._k = np.zeros(0, bool)
        self._buckets: dict[tuple[int, int], list[int]] = {}
        self._tiles_done: set[tuple[int, int]] = set()
        if centers is not None and len(centers):
            self.add(centers, radius, vector, known)

    @property
    def n_lobes(self):
        return self._r.shape[0]

    def add(self, centers, radius, vector, known=None):
        centers = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
        radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), centers.shape[:1])
        vector = np.asarray(vector, dtype=np.float64).reshape(-1, 3)
        known = np.zeros(centers.shape[0], bool) if known is None else np.broadcast_to(np.asarray(known, bool),
                                                                                       centers.shape[:1])
        if np.any(ANOMALY_CUTOFF * radius > self.tile_m):
            raise ValueError("anomaly radius too large for the tile size")
        start = self.n_lobes
        self._c = np.concatenate([self._c, centers])
        self._r = np.concatenate([self._r, radius])
        self._v = np.concatenate([self._v, vector])
        self._k = np.concatenate([self._k, known])
        cells = np.floor(centers / self.tile_m).astype(np.int64)
        for j, (ix, iy) in enumerate(cells.tolist()):
            self._buckets.setdefault((ix, iy), []).append(start + j)

    @staticmethod
    def draw(rng, kind, position, direction, lateral=0.0):
        """Lobes of one anomaly of ``kind`` at ``position`` (x, y) on a road of heading ``direction``.

        Returns (centers (n,2), radius (n,), vector (n,3), known (n,)): a single lobe or, half of
        the time, a dipole-like pair of opposite lobes one radius apart along the road.
        """
        (a_lo, a_hi), (l_lo, l_hi), p_known = ANOMALY_KINDS[kind]
        amp = rng.uniform(a_lo, a_hi)
        r = rng.uniform(l_lo, l_hi) / (2.0 * ANOMALY_FLAG_RADIUS)
        az = rng.uniform(0.0, 2.0 * math.pi)
        v = np.array([amp * math.cos(az), amp * math.sin(az), amp * rng.uniform(-0.7, 0.7)])
        known = rng.random() < p_known
        ux, uy = math.sin(direction), math.cos(direction)  # along the road
        px = position[0] + lateral * uy
        py = position[1] - lateral * ux
        if rng.random() < 0.5:
            return np.array([[px, py]]), np.array([r]), v[None, :], np.array([known])
        h = 0.5 * r
        centers = np.array([[px - h * ux, py - h * uy], [px + h * ux, py + h * uy]])
        return centers, np.array([r, r]), np.stack([v, -0.8 * v]), np.array([known, known])

    def _ensure_tiles(self, cells):
        if self.density_per_km2 <= 0.0:
            return
        # lobes of a tile may sit up to a sixth of a tile outside it: generating the 5 x 5 tiles
        # around a cell makes every lobe bucketed in its 3 x 3 neighbourhood exist, whatever the
        # order in which positions are queried
        for ix, iy in cells:
            for dx in (-2, -1, 0, 1, 2):
                for dy in (-2, -1, 0, 1, 2):
                    key = (ix + dx, iy + dy)
                    if key in self._tiles_done:
                        continue
                    self._tiles_done.add(key)
                    rng = np.random.default_rng([self.seed, key[0] + 2**31, key[1] + 2**31])
                    n = rng.poisson(self.density_per_km2 * (self.tile_m / 1000.0) ** 2)
                    for _ in range(n):
                        kind = self.kinds[rng.integers(len(self.kinds))]
                        pos = (np.array(key) + rng.random(2)) * self.tile_m
                        c, r, v, k = self.draw(rng, kind, pos, rng.uniform(0, 2 * math.pi))
                        self.add(c, np.minimum(r, self.tile_m / ANOMALY_CUTOFF), v, k)

    def _neighbours(self, cell):
        ix, iy = cell
        idx = []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                idx.extend(self._buckets.get((ix + dx, iy + dy), ()))
        return np.asarray(idx, dtype=np.int64)

    def _field_and_flag(self, x, y, lobes):
        d2 = (x[:, None] - self._c[None, lobes, 0]) ** 2 + (y[:, None] - self._c[None, lobes, 1]) ** 2
        r2 = self._r[lobes] ** 2
        field = (np.exp(-d2 / r2) * (d2 < (ANOMALY_CUTOFF**2) * r2)) @ self._v[lobes]
        flag = np.any((d2 < (ANOMALY_FLAG_RADIUS**2) * r2) & self._k[lobes][None, :], axis=1)
        return field, flag

    def evaluate(self, x, y):
        """(anomaly field (N, 3) µT north/east/down, flag (N,) bool) at positions x, y (m); see
        ``disturbance`` and ``unreliable``."""
        x = np.atleast_1d(np.asarray(x, dtype=np.float64))
        y = np.atleast_1d(np.asarray(y, dtype=np.float64))
        field = np.zeros((x.shape[0], 3))
        flag = np.zeros(x.shape[0], bool)
        if x.shape[0] == 1:  # one step of a vehicle model: no grouping
            cell = (int(math.floor(x[0] / self.tile_m)), int(math.floor(y[0] / self.tile_m)))
            self._ensure_tiles([cell])
            lobes = self._neighbours(cell)
            if lobes.size:
                field, flag = self._field_and_flag(x, y, lobes)
            return field, flag
        ix = np.floor(x / self.tile_m).astype(np.int64)
        iy = np.floor(y / self.tile_m).astype(np.int64)
        keys, inverse = np.unique(np.stack([ix, iy], axis=1), axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        self._ensure_tiles([tuple(k) for k in keys.tolist()])
        if self.n_lobes == 0:
            return field, flag
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(keys.shape[0] + 1))
        for j, key in enumerate(keys.tolist()):
            lobes = self._neighbours(tuple(key))
            if lobes.size == 0:
                continue
            pts = order[bounds[j]:bounds[j + 1]]
            field[pts], flag[pts] = self._field_and_flag(x[pts], y[pts], lobes)
        return field, flag

    def disturbance(self, x, y):
        """Anomaly field (north, east, down) in µT at positions x, y (m): shape (N, 3)."""
        return self.evaluate(x, y)[0]

    def unreliable(self, x, y):
        """True where a lobe known to the map is within ANOMALY_FLAG_RADIUS of its radius."""
        return self.evaluate(x, y)[1]


class Transients:
    """Short, spatially unfixed field disturbances (a passing truck, a tram): events of a few seconds.

    Poisson arrivals at ``rate_per_s``, amplitude ``amp_ut`` (µT range), duration ``dur_s`` range, a
    raised-cosine envelope in time and a random direction.
    """

    def __init__(self, rate_per_s=0.0, amp_ut=(1.0, 4.0), dur_s=(1.0, 3.0)):
        self.rate_per_s = float(rate_per_s)
        self.amp_ut = amp_ut
        self.dur_s = dur_s
        self.events: list[tuple[float, float, np.ndarray]] = []  # (start, duration, vector)
        self._until = -math.inf

    def _draw_events(self, t0, t1, rng):
        if self.rate_per_s <= 0.0 or t1 <= t0:
            return
        t = t0
        while True:
            t += rng.exponential(1.0 / self.rate_per_s)
            if t >= t1:
                break
            amp = rng.uniform(*self.amp_ut)
            az = rng.uniform(0.0, 2.0 * math.pi)
            v = np.array([amp * math.cos(az), amp * math.sin(az), amp * rng.uniform(-0.5, 0.5)])
            self.events.append((t, rng.uniform(*self.dur_s), v))

    def evaluate(self, t, rng=None):
        """Disturbance (N, 3) at times t; events are drawn with ``rng`` up to max(t) the first time."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if rng is not None and t.size and t.max() > self._until:
            start = t.min() if self._until == -math.inf else self._until
            self._draw_events(start, float(t.max()) + 1e-9, rng)
            self._until = float(t.max()) + 1e-9
        out = np.zeros((t.shape[0], 3))
        for t_s, dur, v in self.events:
            i0, i1 = np.searchsorted(t, [t_s, t_s + dur])
            if i1 > i0:
                phase = (t[i0:i1] - t_s) / dur
                out[i0:i1] += (0.5 - 0.5 * np.cos(2.0 * math.pi * phase))[:, None] * v[None, :]
        if self.events and t.size:  # forget events that are over
            self.events = [e for e in self.events if e[0] + e[1] > t.max()]
        return out


# ----------------------------------------------------------------------------------------------
# A step-by-step sensor model for a vehicle simulation (the FMU)
# ----------------------------------------------------------------------------------------------

@dataclass
class SensorSample:
    left_pulses: int
    right_pulses: int
    compass_x: float
    compass_y: float
    unreliable_area: bool


class SensorModel:
    """Wheel pulse counters and compass of one vehicle, stepped sample by sample; deterministic per seed.

    ``step(dt, x, y, heading, distance_left, distance_right, pitch, roll)`` takes the vehicle's
    true pose (m, rad, true north clockwise) and its true cumulative wheel distances (m, signed)
    after ``dt`` seconds and returns the sensor readings.  The wheel distances may come from any
    kinematic model (an Ackerman vehicle steered by angle and speed); the model adds the
    differential slip, counts pulses with the TRUE distance per pulse (``dpp_*``, which may differ
    from what the estimator is told) and wraps the counters at ``counter_modulus``.
    """

    def __init__(self, seed=0, *, dpp_left=0.02, dpp_right=0.02, counter_modulus=65536, horizontal=DEFAULT_FIELD_UT,
                 vertical=None, variation_deg=0.0, rotation_deg=0.0, X0=0.0, Y0=0.0, deviation_deg=None,
                 compass_noise_ut=0.35, slip=None, anomalies=None, anomaly_density_per_km2=0.0,
                 transient_rate_per_s=0.0, counter_offsets=None):
        self.rng = np.random.default_rng(seed)
        self.dpp_left, self.dpp_right = float(dpp_left), float(dpp_right)
        self.counter_modulus = int(counter_modulus)
        self.compass = dict(horizontal=horizontal, vertical=vertical, variation_deg=variation_deg,
                            rotation_deg=rotation_deg, X0=X0, Y0=Y0, deviation_deg=deviation_deg)
        self.compass_noise_ut = float(compass_noise_ut)
        self.slip = SlipModel() if slip is None else slip
        if anomalies is None and anomaly_density_per_km2 > 0.0:
            anomalies = AnomalyField(density_per_km2=anomaly_density_per_km2, seed=seed)
        self.anomalies = anomalies
        self.transients = Transients(transient_rate_per_s)
        if counter_offsets is None:
            counter_offsets = self.rng.integers(0, self.counter_modulus, size=2)
        self.offsets = [float(o) for o in counter_offsets]
        self.phases = self.rng.random(2).tolist()
        self.time = 0.0
        self._true = None  # last true wheel distances
        self._measured = [0.0, 0.0]
        self._slip_state = 0.0

    @classmethod
    def from_params(cls, params, seed=0, **kwargs):
        """A SensorModel whose compass and counters are consistent with a flat parameter dict (SPEC §3 keys)."""
        p = dict(params)
        kw = dict(dpp_left=p.get("dpp_left", 0.02), dpp_right=p.get("dpp_right", 0.02),
                  counter_modulus=p.get("counter_modulus", 65536),
                  horizontal=horizontal_field(float(p.get("field_magnitude", 0.0))),
                  variation_deg=p.get("variation_deg", 0.0), rotation_deg=p.get("rotation_deg", 0.0),
                  X0=p.get("X0", 0.0), Y0=p.get("Y0", 0.0), deviation_deg=p.get("deviation_deg"))
        kw.update(kwargs)
        return cls(seed, **kw)

    def step(self, dt, x, y, heading, distance_left, distance_right, pitch=0.0, roll=0.0) -> SensorSample:
        self.time += float(dt)
        dl_true, dr_true = float(distance_left), float(distance_right)
        if self._true is None:
            self._true = (dl_true, dr_true)
        inc_l, inc_r = dl_true - self._true[0], dr_true - self._true[1]
        self._true = (dl_true, dr_true)
        AD = 0.5 * (inc_l + inc_r)
        err, self._slip_state = self.slip.errors(np.array([AD]), self.rng, self._slip_state)
        self._measured[0] += inc_l + 0.5 * err[0]
        self._measured[1] += inc_r - 0.5 * err[0]
        left = int(count_pulses(self._measured[0], self.dpp_left, self.counter_modulus, self.offsets[0],
                                self.phases[0]))
        right = int(count_pulses(self._measured[1], self.dpp_right, self.counter_modulus, self.offsets[1],
                                 self.phases[1]))
        dist = self.transients.evaluate(np.array([self.time]), self.rng)[0]
        unreliable = False
        if self.anomalies is not None:
            field, flag = self.anomalies.evaluate(x, y)
            dist = dist + field[0]
            unreliable = bool(flag[0])
        noise = self.compass_noise_ut * self.rng.standard_normal(2)
        cx, cy = compass_reading(heading, pitch, roll, disturbance_ned=dist, noise=noise, **self.compass)
        return SensorSample(left, right, float(cx), float(cy), unreliable)
