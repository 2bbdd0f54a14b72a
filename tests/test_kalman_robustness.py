"""The Kalman mode (US 4,680,715) outside its tuning: a tyre mismatch the parameters do not know, a wheel sensor that
stops counting, a drive started in a garage, and a reliability output of its own (jaxmodel/kalman.py: beta,
_reacquire, bound)."""

import copy
import dataclasses
import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from identification import scenarios as sc
from jaxmodel import kalman as K
from jaxmodel.heading_filter import reliability as reliability_of_bound
from matrix_drives import heading_error_deg, rmse_after_first_minute, run_drive

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_outside_matrix as outside_matrix  # noqa: E402


def _without_fixes(drive):
    """The drive with its fix columns removed (the Kalman mode without fixes)."""
    return dataclasses.replace(drive, columns={k: v for k, v in drive.columns.items() if not k.startswith("fix")})


def _steps(p, n, compass_heading, e_c, speed=10.0, dt=0.1):
    """n samples straight on, wheel course 0, a valid compass reading ``compass_heading`` (rad) of error bound
    ``e_c`` (rad); Kalman headings and bounds (rad)."""
    ks = K.init_kalman_state(p)._replace(active=jnp.ones(()), speed=jnp.asarray(speed))

    def body(ks, _):
        ks, heading, _, _ = K.kalman_step(
            p, ks, dt=dt, distance=speed * dt, alpha=0.0, wheel_heading=0.0, compass_heading=compass_heading,
            compass_ok=True, e_c=e_c, fix_east=0.0, fix_north=0.0, fix_valid=0.0, odometer_ok=True, initialized=1.0)
        return ks, (heading, K.bound(p, ks, 1.0))

    return jax.lax.scan(body, ks, None, length=n)[1]


def test_a_compass_far_off_restarts_the_course_after_filter_reacquire_lost_m():
    """A compass 100 deg from the course, with the error bound of a field that B_E does not expect (E_C 1 rad: the
    garage's steel had scaled the field B_E was learned from): the running disagreement passes
    filter_reacquire_large_deg within metres, and after filter_reacquire_lost_m (100 m) of it the course restarts
    from the compass.  Meanwhile the bound is at least the disagreement.  Never restarting (the thresholds out of
    reach), the course is still 50 deg off after a kilometre."""
    p = jm.make_params()
    h_c = math.radians(100.0)
    heading, bound = (np.degrees(np.asarray(a)) for a in _steps(p, 1000, h_c, e_c=1.0))  # 1 m per sample
    lost_m = int(p.filter_reacquire_lost_m)
    assert abs(heading[lost_m - 20]) < 20.0                 # still near its own course before
    assert bound[lost_m - 20] > 60.0                        # ... and says the compass contradicts it
    restarted = int(np.argmax(np.abs(heading - 100.0) < 1.0))
    assert lost_m < restarted < lost_m + 20, restarted
    assert np.all(np.abs(heading[restarted:] - 100.0) < 1.0)
    assert bound[-1] < 5.0                                  # the restarted course's own sigma
    never, _ = _steps(p._replace(filter_reacquire_large_deg=1e9, filter_reacquire_m=1e9), 1000, h_c, e_c=1.0)
    assert abs(100.0 - math.degrees(float(never[-1]))) > 30.0


@pytest.mark.slow
@pytest.mark.parametrize("scenario, condition, seed", [("urban", "mismatch_1.5", 102), ("mixed", "mismatch_2.5", 101)])
def test_kalman_mode_follows_a_tyre_mismatch_the_parameters_do_not_know(scenario, condition, seed):
    """The matrix's mismatch drives give the vehicle's nominal distance per pulse on both wheels.  Until the
    calibration has captured the mismatch the wheel course turns 0.3-1 deg per metre; the Kalman filter's beta,
    released by the rate filter's large drift, takes it, and the compass is never held off.  Tuning-side seeds,
    15-minute drives, RMSE after the first minute: before stop 48 the Kalman mode was 101 and 154 deg off with the
    drive's fixes, 153 and 117 without; now 0.65 and 0.93 deg, 1.5 and 2.9 deg."""
    drive = sc.make_drive(scenario, condition, seed)
    rmse = rmse_after_first_minute(run_drive(drive, mode="kalman"), drive)
    assert rmse < 1.5, rmse
    no_fixes = _without_fixes(drive)
    rmse = rmse_after_first_minute(run_drive(no_fixes, mode="kalman"), no_fixes)
    assert rmse < 4.0, rmse


def test_a_substituted_turn_s_uncertainty_is_course_noise():
    """The guard's ``dD_sigma`` / track of a turn it substituted for a wheel that stopped counting enters dth2's
    process noise as its square, as in F-DELTA (offset_filter.predict): 0.01 rad adds 1e-4 rad^2 and nothing else."""
    p = jm.make_params()
    _, q0 = K.transition(p, 0.1, 1.0, 0.3, alpha=0.002)
    _, q1 = K.transition(p, 0.1, 1.0, 0.3, alpha=0.002, turn_sigma=0.01)
    expected = np.zeros((K.N_STATES, K.N_STATES))
    expected[K.I_DRIFT, K.I_DRIFT] = 1e-4
    np.testing.assert_allclose(np.asarray(q1 - q0), expected, atol=1e-15)


@pytest.mark.slow
def test_kalman_mode_hands_the_course_to_the_compass_while_a_wheel_is_stuck():
    """The left sensor stuck for 5 s at 40 % of mixed/baseline/107 (300 s, bench_outside_matrix's stuck_wheel; no
    fixes): the guard substitutes the other wheel's travel and says the turn is unknown.  Until stop 88 the Kalman
    mode ignored that, kept the turns missed during the fault and was 29.8 deg off (RMSE after the first minute);
    with the substituted turn's variance as course noise, 0.81 deg (the clean drive: 0.42 deg)."""
    drive = sc.make_drive("mixed", "baseline", 107, duration_s=300.0)
    stuck = copy.deepcopy(drive)
    outside_matrix._stuck_wheel(stuck)
    stuck = _without_fixes(stuck)
    assert rmse_after_first_minute(run_drive(stuck, mode="kalman"), stuck) < 1.5


@pytest.mark.slow
def test_kalman_mode_finds_its_heading_after_a_garage_start_and_says_when_it_cannot():
    """highway/garage_start/101: the garage's steel turned the first compass samples by 139 deg and the course
    started from them.  Out of the garage the compass disagrees by ~140 deg: the reliability falls to that of a
    heading off by more than filter_reacquire_large_deg, and the course restarts from the compass within seconds
    (with the complementary filter's restart).  The fixes then reposition the position computer, which had
    dead-reckoned 1.5 km with the garage's course: gated, they had pulled the restarted course 57 deg off again.
    Before stop 48 the Kalman mode was off for the whole drive, with the complementary mode's reliability (RMSE
    after the first minute on the 15-minute drive: 112 deg with the fixes, 127 without); now 0.3 deg with them."""
    drive = sc.make_drive("highway", "garage_start", 101, duration_s=450.0)
    out = run_drive(drive, mode="kalman")
    err = heading_error_deg(out, drive)
    assert rmse_after_first_minute(out, drive) < 5.0
    t = drive.truth["time_s"]
    leave = drive.notes["garage_start"]["leave_s"]
    reliability = np.asarray(out.heading_reliability)
    far_out = (t > leave) & (np.abs(err) > 90.0)
    assert far_out.any()
    assert np.all(np.abs(err[t > leave + 5.0]) < 5.0), np.abs(err[t > leave + 5.0]).max()
    p = jm.make_params(drive.params)
    floor = float(reliability_of_bound(p, math.radians(p.filter_reacquire_large_deg)))
    assert np.all(reliability[far_out] <= floor), reliability[far_out].max()
    assert np.all(reliability[(t > 120.0)] > floor)


@pytest.mark.slow
def test_kalman_mode_with_fixes_restarts_a_garage_course_the_compass_and_the_fixes_both_contradict():
    """mixed/garage_start/102 with its 1-Hz fixes: the course started 61 deg off from the garage's compass, and the
    fixes of the first 30 s (the car still inside) pulled it to 54 deg off, below filter_reacquire_large_deg, so the
    clean compass outside could not restart it; the fixes, rejected in a row, moved it by ~0.3 deg/s while dth2's
    sigma said 0.8 deg.  Until stop 91: 10.7 deg RMSE after the first minute on the 15-minute drive (0.85 without the
    fixes), 20.8 deg on these 300 s.  Now the compass's disagreement beyond CORROBORATED_DISAGREEMENT_DEG, with the
    fixes rejected CORROBORATING_FIX_COUNT times in a row, restarts the course after CORROBORATED_M (the count held
    while a repositioning starts the fixes' count again): within 25 s of leaving the garage, 0.4 deg on the 15-minute
    drive."""
    drive = sc.make_drive("mixed", "garage_start", 102, duration_s=300.0)
    out = run_drive(drive, mode="kalman")
    err = heading_error_deg(out, drive)
    leave = drive.notes["garage_start"]["leave_s"]
    t = drive.truth["time_s"]
    assert np.abs(err[t < leave]).min() > 40.0               # the garage's course, as the fixes left it
    assert rmse_after_first_minute(out, drive) < 1.5
    assert np.all(np.abs(err[t > leave + 25.0]) < 5.0), np.abs(err[t > leave + 25.0]).max()
