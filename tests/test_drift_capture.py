"""jaxmodel/drift_capture.py: a drift the stretches corroborate restarts the follow hold (stop 53)."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from jaxmodel import calibration as cal
from jaxmodel import drift_capture as dc
from jaxmodel import offset_filter as of

TRACK = 1.65


def _rate_filter(params, beta, sigma_beta):
    f = of.init_offset_state(params).fields()
    return of.OffsetState.pack(f._replace(beta=jnp.asarray(beta), p11=jnp.asarray(sigma_beta ** 2)))


def _stretches(params, gap, sigma):
    """A calibration state whose filtered mean is ``gap`` below the applied ratio, with the mean's sigma ``sigma``
    (ten stretches of equal weight: var_mean = (m2 + 2 s0^2) / 12 / 10)."""
    f = cal.init_calibration_state(params).fields()
    n = 10.0
    m2 = sigma ** 2 * n * (n + cal.SIGMA_PRIOR_STRETCHES) - cal.SIGMA_PRIOR_STRETCHES * params.cal_stretch_sigma ** 2
    k = f.ratio
    return cal.CalibrationState.pack(f._replace(mean=k - gap, weight=jnp.asarray(n), weight2=jnp.asarray(n),
                                                m2=jnp.asarray(m2)))


def test_stretches_rate_is_the_unapplied_gap_over_the_track_with_its_significance():
    params = jm.make_params()
    rate, z = cal.stretches_rate(params, _stretches(params, 1.6e-4, 8e-5), jnp.asarray(TRACK))
    assert float(rate) == pytest.approx(1.6e-4 / TRACK, rel=1e-9)
    assert float(z) == pytest.approx(2.0, rel=1e-9)


@pytest.mark.parametrize("beta, sigma_beta, gap, sigma_gap, expected", [
    (80e-6, 15e-6, 1.6e-4, 8e-5, True),      # highway seed 61 at 300-400 s: both see ~90 µrad/m
    (-80e-6, 15e-6, -1.6e-4, 8e-5, True),    # the other wheel
    (80e-6, 15e-6, -1.6e-4, 8e-5, False),    # opposite directions
    (80e-6, 25e-6, 1.6e-4, 8e-5, False),     # the rate at 3.2 sigmas (a hill's fake reaches 4.7; this alone: no)
    (80e-6, 15e-6, 1.6e-4, 1.2e-4, False),   # the stretches at 1.3 sigmas
    (80e-6, 15e-6, 4.5e-4, 1e-4, False),     # the stretches say 270 µrad/m: more than twice the rate
    (80e-6, 15e-6, 0.6e-4, 2e-5, False),     # ... 36 µrad/m: less than half
    (30e-6, 5e-6, 0.5e-4, 2e-5, False),      # too small to drift F-DELTA 2 deg in a km (drifting)
])
def test_corroborated_needs_both_measurements_in_one_direction_and_size(beta, sigma_beta, gap, sigma_gap, expected):
    params = jm.make_params()
    got = dc.corroborated(params, _stretches(params, gap, sigma_gap), _rate_filter(params, beta, sigma_beta),
                          jnp.asarray(TRACK))
    assert bool(got) is expected


def test_a_corroborated_drift_restarts_the_steady_filters_hold_and_the_rate_filters_count():
    """calibrate: with the stretches and the rate filter agreeing, the steady filter's since_drift (the follow hold)
    and the rate filter's (the window for recalibrations) restart; the ratio itself is not moved by it."""
    params = jm.make_params()
    calib = _stretches(params, 1.6e-4, 8e-5)
    rate = _rate_filter(params, 80e-6, 15e-6)
    steady = of.OffsetState.pack(of.init_offset_state(of.steady_params(params)).fields())
    odo = dict(n_left=jnp.asarray(0.0), n_right=jnp.asarray(0.0), d_t=jnp.asarray(0.0), plausible=jnp.asarray(True),
               counted=jnp.asarray(True),
               track=jnp.asarray(TRACK))
    for agree, since in ((True, 0.0), (False, of.NEVER_DRIFTED_M)):
        cs = calib if agree else _stretches(params, -1.6e-4, 8e-5)
        new_cal, new_rate, new_steady, rate_change = dc.calibrate(
            params, cs, jm.Config(), odo, jnp.asarray(0.0), jnp.asarray(True), rate, steady, jnp.asarray(1.0))
        assert float(new_steady.fields().since_drift) == since
        assert float(new_rate.fields().since_drift) == (0.0 if agree else float(rate.fields().since_drift))
        assert float(new_cal.fields().ratio) == float(cs.fields().ratio) and float(rate_change) == 0.0
    assert np.isfinite(float(new_rate.beta))


def _correlated_rate_filter(params):
    """A rate filter whose offset and rate are correlated (as after kilometres of compass), rate 60 µrad/m."""
    f = of.init_offset_state(params).fields()
    return of.OffsetState.pack(f._replace(beta=jnp.asarray(60e-6), p00=jnp.asarray(4e-4), p01=jnp.asarray(-2e-7),
                                          p11=jnp.asarray((50e-6) ** 2)))


def test_a_stretch_measures_the_rate_as_a_kalman_update():
    """measure_rate is the scalar Kalman update with h = e_beta: the state moves by P h / (h P h + r) times the
    innovation, the covariance loses the gain's outer product; nothing moves without a stretch."""
    params = jm.make_params()
    fs = _correlated_rate_filter(params)
    f = fs.fields()
    P = np.array([[float(getattr(f, f"p{min(i, j)}{max(i, j)}")) for j in range(len(of.STATES))]
                  for i in range(len(of.STATES))])
    x = np.array([float(getattr(f, s)) for s in of.STATES])
    y, r = -20e-6, (90e-6) ** 2
    gain = P[:, 1] / (P[1, 1] + r)
    want_x = x + gain * (y - x[1])
    want_P = P - np.outer(gain, P[1])
    got = dc.measure_rate(fs, jnp.asarray(y), jnp.asarray(r), jnp.asarray(True)).fields()
    np.testing.assert_allclose([float(getattr(got, s)) for s in of.STATES], want_x, rtol=1e-12, atol=1e-18)
    for i in range(len(of.STATES)):
        for j in range(i, len(of.STATES)):
            assert float(getattr(got, f"p{i}{j}")) == pytest.approx(want_P[i, j], rel=1e-9, abs=1e-24)
    assert float(got.delta) > float(f.delta)  # the offset moves too: negatively correlated, the rate fell
    unchanged = dc.measure_rate(fs, jnp.asarray(y), jnp.asarray(r), jnp.asarray(False))
    np.testing.assert_array_equal(np.asarray(unchanged.vector), np.asarray(fs.vector))


def test_a_stretch_far_from_the_rate_counts_less():
    """Beyond STRETCH_GATE sigmas of the innovation the stretch's variance grows with it (a curve the compass did
    not see): the rate moves less than the plain update would move it, and in the same direction."""
    params = jm.make_params()
    fs = _correlated_rate_filter(params)
    r = (90e-6) ** 2
    s = float(fs.fields().p11) + r
    far = 60e-6 - 10.0 * np.sqrt(s)
    plain = 60e-6 + float(fs.fields().p11) / s * (far - 60e-6)
    got = float(dc.measure_rate(fs, jnp.asarray(far), jnp.asarray(r), jnp.asarray(True)).beta)
    assert plain < got < 60e-6


def test_stretch_rate_is_the_gap_to_the_ratio_in_force_with_the_stretchs_weight():
    """stretch_rate: (k - k_s) / T with the variance (cal_stretch_sigma / T)^2 / w, w the stretch's intensity found from
    the filtered ratio's weight; only where a stretch completed."""
    params = jm.make_params()
    before = _stretches(params, 0.0, 8e-5)
    b = before.fields()
    k_s, w = float(b.ratio) + 3e-4, 0.4
    weight = float(b.weight) * (1.0 - w / float(params.cal_filter_stretches)) + w
    after = cal.CalibrationState.pack(b._replace(updates=b.updates + 1.0, prev_k=jnp.asarray(k_s),
                                                 weight=jnp.asarray(weight)))
    rate, variance, done = dc.stretch_rate(params, before, after, jnp.asarray(TRACK))
    assert bool(done)
    assert float(rate) == pytest.approx(-3e-4 / TRACK, rel=1e-9)
    assert float(variance) == pytest.approx((float(params.cal_stretch_sigma) / TRACK) ** 2 / w, rel=1e-9)
    assert not bool(dc.stretch_rate(params, before, before, jnp.asarray(TRACK))[2])


@pytest.mark.slow
def test_the_stretches_keep_a_found_mismatchs_rate_from_the_compass():
    """Held-out highway/mismatch_2.5/111: after a 4-deg disturbance the rate filter had learned a rate from it and the
    steady filter rejected a clean compass for 2.2 km (2.15 deg RMSE).  Each completed stretch now measures the rate
    (drift_capture.measure_rate, docs/tuning.md stop 54): 0.87 deg."""
    from identification import scenarios as sc
    from matrix_drives import rmse_after_first_minute, run_drive

    drive = sc.make_drive("highway", "mismatch_2.5", 111)
    assert rmse_after_first_minute(run_drive(drive), drive) < 1.3
