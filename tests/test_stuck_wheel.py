"""A wheel sensor that stops counting (plausibility.impossible): a front-axle curvature no vehicle can drive, or on
either axle a lateral acceleration no tyre can give, is substituted however long it lasts; real turns at the
geometric maximum curvature, bursts at speed and rear-axle pivots are believed (or removed as bursts).  The whole
estimator on a drive with a stuck sensor: tests/test_scenarios.py."""

import jax.numpy as jnp
import numpy as np

import jaxmodel as jm
from jaxmodel import plausibility
from jaxmodel.track import max_curvature


def _guard_run(params, d_left, d_right, dt=0.1):
    """The guard alone over per-sample wheel increments (m); returns the kept (d_left, d_right) per sample, (n, 2),
    and its dD_sigma (m) per sample."""
    gs = plausibility.init_guard_state()
    kept, sigmas = [], []
    for i, (left, right) in enumerate(zip(d_left, d_right)):
        out = plausibility.guard(params, gs, jnp.asarray(left), jnp.asarray(right), jnp.asarray(dt),
                                 jnp.asarray(i > 0), jnp.asarray(i > 0), params.dpp_left, params.dpp_right)
        gs = out[-1]
        kept.append((float(out[0]), float(out[1])))
        sigmas.append(float(out[-2]))
    return np.array(kept), sigmas


def _quantized(distance, dpp):
    """Per-sample increments (m) of a pulse counter whose wheel travelled ``distance`` (cumulative, m)."""
    return np.diff(np.floor(np.concatenate([[0.0], distance]) / dpp)) * dpp


def test_a_turn_at_the_geometric_maximum_curvature_is_believed():
    params = jm.make_params({"dpp_left": 0.02, "dpp_right": 0.02})
    c = 0.95 * float(max_curvature(params.B, params.T_F))  # dD/AD of a full-lock turn
    n, speed = 400, 1.5
    ad = np.full(n, speed * 0.1)
    ad[:50] = np.linspace(0.0, speed * 0.1, 50)  # pulling away at full lock
    s = np.cumsum(ad)
    left, right = _quantized(s * (1.0 + c / 2.0), 0.02), _quantized(s * (1.0 - c / 2.0), 0.02)
    kept, _ = _guard_run(params, left, right)
    np.testing.assert_allclose(np.cumsum(kept[:, 0] - kept[:, 1])[-1], np.cumsum(left - right)[-1], atol=0.041)


def test_a_stuck_front_wheel_is_substituted_for_its_whole_length_and_a_rear_axle_pivot_is_believed():
    n, step = 200, 0.15  # 1.5 m/s straight ahead, the left sensor counting nothing from sample 50 to 150
    right = _quantized(np.cumsum(np.full(n, step)), 0.02)
    left = right.copy()
    left[50:150] = 0.0
    front = jm.make_params({"dpp_left": 0.02, "dpp_right": 0.02})
    kept, sigmas = _guard_run(front, left, right)
    # More than GUARD_MAX_SUBSTITUTED (20) samples: the stuck wheel is still replaced by the other's travel.
    assert plausibility.GUARD_MAX_SUBSTITUTED < 100
    assert abs(np.sum(kept[:, 0] - kept[:, 1])) < 0.1, np.sum(kept[:, 0] - kept[:, 1])  # raw: -15 m of dD
    # ... and the filter is told its turn is unknown on each substituted sample (c_max times the travel).
    assert all(v > 0.0 for v in sigmas[55:150]) and all(v == 0.0 for v in sigmas[:50] + sigmas[160:])
    # A skid-steer (rear-axle sensors) may pivot about one track: after GUARD_MAX_SUBSTITUTED it is believed.
    rear = jm.make_params({"dpp_left": 0.02, "dpp_right": 0.02, "sensor_axle": "rear"})
    kept, _ = _guard_run(rear, left, right)
    assert np.sum(kept[:, 0] - kept[:, 1]) < -10.0


def test_a_stuck_rear_wheel_at_speed_is_substituted_and_a_burst_at_speed_is_removed_as_a_burst():
    """Rear-axle sensors have no geometric bound (a skid-steer pivots), but at 10 m/s a wheel that reads nothing
    is a lateral acceleration of v^2 / (2 T) = 33 m/s^2 (MAX_LATERAL_ACCEL 12)."""
    rear = jm.make_params({"dpp_left": 0.02, "dpp_right": 0.02, "sensor_axle": "rear", "T_R": 1.5})
    n, step = 300, 1.0  # 10 m/s straight ahead, the left sensor counting nothing from sample 100 to 200
    right = _quantized(np.cumsum(np.full(n, step)), 0.02)
    left = right.copy()
    left[100:200] = 0.0
    kept, sigmas = _guard_run(rear, left, right)
    assert abs(np.sum(kept[:, 0] - kept[:, 1])) < 0.1, np.sum(kept[:, 0] - kept[:, 1])  # raw: -100 m of dD
    np.testing.assert_allclose(kept[100:200, 0], right[100:200])  # the travel kept: the other wheel's
    assert all(v > 0.0 for v in sigmas[100:200]) and all(v == 0.0 for v in sigmas[:100] + sigmas[200:])
    # A burst of 25 pulses on one wheel at 30 m/s is also far beyond the bound for its one sample; it is removed
    # by the course check (a glitch: no wheel reads nothing) and the wheels' turn stays what it was.
    right = _quantized(np.cumsum(np.full(n, 3.0)), 0.02)
    left = right.copy()
    left[150:] += 25 * 0.02
    left = np.diff(np.concatenate([[0.0], left]))
    right = np.diff(np.concatenate([[0.0], right]))
    kept, sigmas = _guard_run(rear, left, right)
    assert abs(np.sum(kept[:, 0] - kept[:, 1])) <= 0.021 and not any(sigmas)


def test_a_skid_steer_pivot_is_believed():
    """Wheels turning opposite ways at 1 m/s (AD = 0): no lateral acceleration of the axle, however tight the turn."""
    rear = jm.make_params({"dpp_left": 0.02, "dpp_right": 0.02, "sensor_axle": "rear", "T_R": 0.55})
    step = np.full(200, 0.1)
    step[:50] = np.linspace(0.0, 0.1, 50)  # starting to pivot
    s = np.cumsum(step)
    left, right = _quantized(s, 0.02), -_quantized(s, 0.02)
    kept, sigmas = _guard_run(rear, left, right)
    np.testing.assert_allclose(np.sum(kept[:, 0] - kept[:, 1]), np.sum(left - right), atol=0.041)
    assert not any(sigmas)


def test_one_over_counting_sample_is_a_burst_and_a_chattering_wheel_stays_impossible():
    """Front axle at 4 m/s: 30 spurious pulses of 2 cm on the left wheel in one sample is dD/AD = 1.5, beyond twice
    eq. (14)'s largest curvature, yet both wheels count and the left one beyond its rate: a burst, removed with the
    turn kept and no dD_sigma (it was substituted as a stuck wheel, its turn unknown).  The same 30 pulses on every
    sample of a second (a chattering sensor) are impossible from the second sample on: substituted, the turn
    handed to the filter as unknown, and none of the extra pulses kept."""
    params = jm.make_params({"dpp_left": 0.02, "dpp_right": 0.02})
    n = 200
    right = _quantized(np.cumsum(np.full(n, 0.4)), 0.02)
    burst = right.copy()
    burst[100] += 30 * 0.02
    kept, sigmas = _guard_run(params, burst, right)
    assert abs(np.sum(kept[:, 0] - kept[:, 1])) < 0.021 and all(v == 0.0 for v in sigmas)
    chatter = right.copy()
    chatter[100:110] += 30 * 0.02
    kept, sigmas = _guard_run(params, chatter, right)
    assert abs(np.sum(kept[:, 0] - kept[:, 1])) < 0.021
    assert sigmas[100] == 0.0 and all(v > 0.0 for v in sigmas[101:110]) and all(v == 0.0 for v in sigmas[111:])
