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
               track=jnp.asarray(TRACK))
    for agree, since in ((True, 0.0), (False, of.NEVER_DRIFTED_M)):
        cs = calib if agree else _stretches(params, -1.6e-4, 8e-5)
        new_cal, new_rate, new_steady, rate_change = dc.calibrate(
            params, cs, jm.Config(), odo, jnp.asarray(0.0), jnp.asarray(True), rate, steady, jnp.asarray(1.0))
        assert float(new_steady.fields().since_drift) == since
        assert float(new_rate.fields().since_drift) == (0.0 if agree else float(rate.fields().since_drift))
        assert float(new_cal.fields().ratio) == float(cs.fields().ratio) and float(rate_change) == 0.0
    assert np.isfinite(float(new_rate.beta))
