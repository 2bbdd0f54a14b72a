"""A small tyre drift the heading shows (stop 66): the straight stretches agreeing with the rate filter
(follow.stretches_agree) let the heading show the rate filter's drift below filter_follow_show_rate.  A unit check of
the agreement, and one drive of the independent simulator (bench/independent_sim.py, diagnosis seed 31) whose parameter
file has the right wheel's distance per pulse 40 ppm off."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from independent_drives import heading_error_deg, independent_sim, rmse_after_first_minute, unidentified_params
from jaxmodel import calibration, follow, offset_filter


def _rate_filter(params, beta):
    fields = offset_filter.init_offset_state(params).fields()
    return offset_filter.OffsetState.pack(fields._replace(beta=jnp.asarray(beta)))


def _calibration(params, mean_less_ratio, stretches):
    """A calibration state whose stretches' filtered ratio is ``mean_less_ratio`` below the applied one (relative),
    from ``stretches`` stretches of weight 1 that all measured it (no spread)."""
    f = calibration.init_calibration_state(params).fields()
    w = jnp.asarray(float(stretches))
    return calibration.CalibrationState.pack(f._replace(mean=f.ratio * (1.0 - mean_less_ratio), weight=w, weight2=w))


def test_stretches_agree_only_in_the_rate_filters_direction_and_beyond_their_sigma():
    params = jm.make_params({})
    track = jnp.asarray(1.6)
    # 50 stretches without spread: the filtered ratio's sigma is cal_stretch_sigma sqrt(2/52/50) = 4.2e-6.
    sure, unsure = _calibration(params, 4e-5, 50), _calibration(params, 6e-6, 50)
    assert bool(follow.stretches_agree(params, sure, _rate_filter(params, 25e-6), track))
    assert not bool(follow.stretches_agree(params, sure, _rate_filter(params, -25e-6), track))
    # 1.4 sigmas: under AGREED_STRETCH_Z (chance agreements at 1-2 sigmas showed a hill's fake rate).
    assert not bool(follow.stretches_agree(params, unsure, _rate_filter(params, 3.75e-6), track))
    # No stretch yet: the prior alone says nothing.
    assert not bool(follow.stretches_agree(params, calibration.init_calibration_state(params),
                                           _rate_filter(params, 25e-6), track))



@pytest.mark.slow
def test_a_ratio_40_ppm_off_the_file_is_followed_on_the_highway(tmp_path, traced_constants):
    """Highway seed 31, every feature on, the tyres' dpp given but the right one 4e-5 high: ~25 µrad/m of drift, under
    the show rate and the calibration's significance.  The steady filter lagged it and then rejected the clean compass
    for kilometres: 11.46 deg RMSE.  Shown while the stretches agree: 4.38 deg (the same drive with the file's ratio
    exact: 0.68)."""
    path, pp = independent_sim.make_drive("highway", 31, tmp_path)
    params = unidentified_params(pp)
    params = params._replace(dpp_right=params.dpp_right * (1.0 + 4e-5))
    shown = rmse_after_first_minute(*heading_error_deg(path, params))
    with traced_constants((follow, "AGREED_STRETCH_Z", np.inf)):
        lagged = rmse_after_first_minute(*heading_error_deg(path, params))
    assert shown < 0.6 * lagged
    assert shown < 6.0
