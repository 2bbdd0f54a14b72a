"""The default mode comes back after it was wrong (issue 10, stop 50): drives of the independent simulator
(bench/independent_sim.py) on which the heading stayed far off a clean compass."""

import jax.numpy as jnp
import numpy as np
import pytest


from independent_drives import heading_error_deg, independent_sim, unidentified_params


def _error_deg(tmp_path, kind, seed, hide_mismatch=False, read_field=True, disable=()):
    """(time s, heading error deg) of the default mode on an independent drive; ``hide_mismatch`` gives both wheels
    the tyres' mean distance per pulse (what bench_independent.py --hide-mismatch does); ``read_field`` False sets
    filter_field_sigma 0 (|B| not read; the default reads it against the drive's field_magnitude,
    jaxmodel/field_tilt.py); ``disable``: the simulator's features switched off."""
    path, params_path = independent_sim.make_drive(kind, seed, tmp_path, disable=disable)
    params = unidentified_params(params_path)
    if hide_mismatch:
        mean = 0.5 * (params.dpp_left + params.dpp_right)
        params = params._replace(dpp_left=mean, dpp_right=mean)
    if not read_field:
        params = params._replace(filter_field_sigma=jnp.asarray(0.0))
    return heading_error_deg(path, params)


@pytest.mark.slow
def test_a_start_on_a_grade_is_restarted_after_the_first_turn(tmp_path):
    """urban_hilly seed 20: started heading magnetic west on a 9 % grade, 12.6 deg off; after the first turn (28 s) the
    compass was within 3 deg, disagreeing steadily by 10 deg, and the filter took 10 minutes to come back (-7.7 deg at
    120 s, -5 deg at 300 s).  The young restart (offset_filter.young), |B| not read: within 1.3 deg from 140 to 240
    s.  (With |B| read as the grade, jaxmodel/field_tilt.py, the default: a lower RMSE, 2.0 deg at worst in that
    window.)"""
    t, err = _error_deg(tmp_path, "urban_hilly", 20, read_field=False)
    assert abs(err[0]) > 10.0  # the start on the grade
    assert np.max(np.abs(err[(t > 140.0) & (t < 240.0)])) < 1.5
    # Reading |B| (the default since stop 59) takes more of the grade out over the drive, less in that window.
    t, read = _error_deg(tmp_path, "urban_hilly", 20)
    assert np.sqrt(np.mean(read[t >= 60.0] ** 2)) < np.sqrt(np.mean(err[t >= 60.0] ** 2))
    assert np.max(np.abs(read[(t > 140.0) & (t < 240.0)])) < 2.5


@pytest.mark.slow
def test_a_steady_filter_locked_out_by_a_slow_hidden_drift_comes_back(tmp_path):
    """mixed seed 25 with its 0.1 % tyre mismatch hidden (660 µrad/m of wheel drift until the calibration finds it):
    the rate filter followed the drift and accepted the compass, the steady filter lagged 30 deg and was rejected;
    once the calibration's first step took the rate under the show rate (240 s), the heading was the steady filter's,
    32 deg off for 4.6 km (18.4 deg RMSE).  The far restart alone: 7.25 deg; with the steady filter taking the rate
    filter's offset: 5.67 deg, within 6.8 deg from 270 s on.  Since filter_follow_hold_rate is 5e-4 rad/m (stop 52)
    the drift is captured and the steady filter held to the rate filter from the start: 1.71 deg, within 4.9 deg
    from 270 s on."""
    t, err = _error_deg(tmp_path, "mixed", 25, hide_mismatch=True)
    assert np.max(np.abs(err[t > 270.0])) < 6.0
    assert np.sqrt(np.mean(err[t >= 60.0] ** 2)) < 3.0


@pytest.mark.slow
def test_a_slow_hidden_drift_is_captured_and_followed(tmp_path):
    """highway seed 26 with its 0.16 % tyre mismatch hidden: the rate filter measured -600 to -820 µrad/m from 30 s
    on, under the 1e-3 rad/m of a large drift, so nothing captured it and no follow hold started; the steady filter
    lagged 10-38 deg, shown whenever the rate's significance dipped (3.93 deg RMSE, 11.6 deg at worst).  With
    filter_follow_hold_rate 5e-4 rad/m (docs/tuning.md, stop 52): 0.79 deg, 2.5 deg at worst.  (|B| read as the
    grade's and the roll's errors, jaxmodel/field_tilt.py, makes it 1.04 deg RMSE, 5.1 deg at worst: stop 58.)"""
    t, err = _error_deg(tmp_path, "highway", 26, hide_mismatch=True)
    after_first_minute = err[t >= 60.0]
    assert np.sqrt(np.mean(after_first_minute ** 2)) < 1.5
    assert np.max(np.abs(after_first_minute)) < 4.0


@pytest.mark.slow
def test_an_anchored_filter_is_not_restarted_by_a_strong_anomaly(tmp_path):
    """mixed seed 47, 13 km into the drive: an anomaly of 16 µT on the 22 µT field turned the compass 45-60 deg for
    250 m, wandering 5-15 deg RMS (under LOST_STEADY_DEG, 15 deg), and the filter restarted from it as lost: 57 deg off
    for 110 m, 5.79 deg RMSE.  An anchored filter is lost only to a steady compass (offset_filter.MATURE_STEADY_DEG):
    1.81 deg."""
    t, err = _error_deg(tmp_path, "mixed", 47)
    assert np.sqrt(np.mean(err[t >= 60.0] ** 2)) < 2.5
    assert np.max(np.abs(err[(t > 840.0) & (t < 880.0)])) < 8.0


@pytest.mark.slow
def test_after_a_found_hidden_mismatch_the_heading_does_not_chase_the_compass_at_turns(tmp_path):
    """urban seed 29 with its 0.7 % tyre mismatch hidden: the calibration finds it and the steady filter takes the rate
    filter's state for the follow hold, whose turn noise (16 % of each turn) let the heading follow the compass's
    error at every corner: 3.03 deg against 1.93 deg with the mismatch given.  Once the ratio has moved, the rate
    filter's turn noise is halfway to the steady filter's (follow.calibrated_rate_params, docs/tuning.md stop 53):
    1.57 deg."""
    t, err = _error_deg(tmp_path, "urban", 29, hide_mismatch=True)
    assert np.sqrt(np.mean(err[t >= 60.0] ** 2)) < 2.2


@pytest.mark.slow
def test_a_small_hidden_drift_the_stretches_corroborate_is_followed(tmp_path):
    """highway seed 61 with its 0.017 % tyre mismatch hidden: the rate filter measured 70-90 µrad/m at 4-6 sigmas for
    10 km, under the large drift and the show rate; the stretches' mean said the same at 1.3-2.8 sigmas, under their
    significance, for 20 km.  The steady filter lagged the drift by 17 deg (10.5 deg RMSE).  Both measurements agreeing
    restart the follow hold (drift_capture.corroborated, docs/tuning.md stop 53): 3.6 deg; 4.6 since stop 54 (more
    stretches on coarse pulses and each measuring the rate: a few fewer corroborations)."""
    t, err = _error_deg(tmp_path, "highway", 61, hide_mismatch=True)
    assert np.sqrt(np.mean(err[t >= 60.0] ** 2)) < 5.0


@pytest.mark.slow
def test_the_field_magnitude_read_takes_the_grades_out_of_the_heading(tmp_path):
    """urban_hilly seed 94 with only anomalies and hills (tyre slip, road noise, the compass's calibration error, soft
    iron, body tilt and the mount's rotation switched off, as in the issue's description of its evaluation): 8-10 %
    grades at a dip of 60-70 deg turn the compass by up to 15 deg.  The default is 2.26 deg RMSE; with |B| read against the
    drive's B_E (filter_field_sigma 0.02) as the grade heading north or south and the roll (jaxmodel/field_tilt.py):
    0.63 deg."""
    off = ("slip", "road_noise", "calib_error", "soft_iron", "tilt", "mount_rotation")
    t, err = _error_deg(tmp_path, "urban_hilly", 94, disable=off, read_field=True)
    assert np.sqrt(np.mean(err[t >= 60.0] ** 2)) < 1.0
    t, err = _error_deg(tmp_path, "urban_hilly", 94, disable=off, read_field=False)
    assert np.sqrt(np.mean(err[t >= 60.0] ** 2)) > 1.5
