"""The Kalman mode's heading started from position fixes when no compass has (SPEC §8; jaxmodel/fix_alignment.py)."""

import math

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from jax.test_util import check_grads

import jaxmodel as jm
from identification import scenarios as sc
from jaxmodel import fix_alignment as FA
from jaxmodel.heading_filter import reliability as reliability_of_bound
from jaxmodel.offset_filter import UNINITIALIZED_BOUND
from matrix_drives import after_first_minute, heading_error_deg, rmse, run_drive


def _track(n, dt=0.1, speed=8.0, turn_at=150, turn_rate=0.15):
    """A track in the frame of an unstarted wheel heading: straight, then a steady left turn (course rad, AD m)."""
    course = np.cumsum(np.where(np.arange(n) >= turn_at, -turn_rate * dt, 0.0))
    return course, np.full(n, speed * dt)


def _align(params, course, distance, rotation, fix_sigma, rng, every=10, dt=0.1, fixes=None):
    """Runs fix_alignment.update over a track whose true course is course + rotation, with fixes every ``every``
    samples (white errors of ``fix_sigma`` m, or the given ``fixes``); returns (aligned, theta, sigma) per sample."""
    true = course + rotation
    east = np.cumsum(distance * np.sin(true)) + 1000.0
    north = np.cumsum(distance * np.cos(true)) - 500.0
    if fixes is None:
        fixes = (east + fix_sigma * rng.standard_normal(east.size), north + fix_sigma * rng.standard_normal(east.size))
    valid = (np.arange(course.size) % every == 0).astype(float)
    mid = course - 0.5 * np.diff(course, prepend=0.0)

    def body(al, x):
        d, c, fe, fn, v = x
        al, aligned, theta, sigma = FA.update(params, al, dt=dt, distance=d, course=c, fix_east=fe, fix_north=fn,
                                              fix_valid=v, waiting=True)
        return al, (aligned, theta, sigma)

    xs = tuple(jnp.asarray(v) for v in (distance, mid, fixes[0], fixes[1], valid))
    return jax.device_get(jax.lax.scan(body, FA.init_alignment_state(), xs)[1])


def test_the_rotation_of_the_wheels_track_onto_the_fixes_is_the_missing_heading():
    """A true course 130 deg from the unstarted wheel heading: once the fixes determine the rotation within
    ALIGN_SIGMA_DEG it is within 3 of its sigmas of 130 deg, and it only gets better with more fixes."""
    p = jm.make_params()
    rng = np.random.default_rng(3)
    course, distance = _track(600)
    aligned, theta, sigma = _align(p, course, distance, math.radians(130.0), 2.0, rng)
    first = int(np.argmax(aligned))
    assert aligned.any() and 4 * 10 <= first < 600
    assert sigma[first] <= math.radians(FA.ALIGN_SIGMA_DEG)
    assert abs(math.degrees(theta[first]) - 130.0) <= 3.0 * math.degrees(sigma[first])
    last = 590  # the last fix (theta and sigma are those of a fix's sums on fix samples only)
    assert abs(math.degrees(theta[last]) - 130.0) < 1.0 and sigma[last] < sigma[first]


def test_fewer_than_align_min_fixes_start_nothing():
    """Four perfect fixes 30 m apart already fix the rotation within ALIGN_SIGMA_DEG, but ALIGN_MIN_FIXES is five:
    the fifth starts the heading."""
    p = jm.make_params()
    course, distance = _track(50, speed=30.0, turn_at=1000)
    aligned, theta, sigma = _align(p, course, distance, 0.5, 0.0, np.random.default_rng(0))
    assert abs(theta[30] - 0.5) < 1e-9 and sigma[30] <= math.radians(FA.ALIGN_SIGMA_DEG)  # four fixes (0-30)
    assert not aligned[:40].any() and aligned[40]


def test_fixes_that_do_not_follow_the_wheels_start_nothing():
    """Fixes scattered over 500 m (a receiver with no solution reporting valid): the residual restarts the sums
    and the heading is never started."""
    p = jm.make_params()
    rng = np.random.default_rng(1)
    course, distance = _track(3000)
    scattered = (500.0 * rng.standard_normal(3000), 500.0 * rng.standard_normal(3000))
    aligned, _, _ = _align(p, course, distance, 1.0, 0.0, rng, fixes=scattered)
    assert not aligned.any()


def test_rotation_gradients_match_finite_differences():
    fields = FA.AlignmentFields(*[jnp.asarray(v) for v in (
        1.0, 3.0, 40.0, 5.0, 6.0, 12.0, 11.0, 30.0, 200.0, 25.0, 190.0, 4000.0, 900.0, 4300.0, 5000.0,
        0.0, 0.0, 0.0, 0.0)])

    def f(sums):
        a = fields._replace(sum_pe=sums[0], sum_pn=sums[1], sum_fe=sums[2], sum_fn=sums[3], sum_dot=sums[4],
                            sum_cross=sums[5])
        theta, sigma, rms = FA.rotation(a, 2.2, 1.2, 28.0)
        return jnp.stack([theta, sigma, rms])

    check_grads(f, (jnp.asarray([30.0, 200.0, 25.0, 190.0, 4000.0, 900.0]),), order=1, modes=("fwd", "rev"))


def test_gradients_through_a_start_from_fixes_are_finite():
    """No compass, 20 s standing with fixes (the rotation's sums all zero: arctan2(0, 0)), then driving a curve until
    the fixes start the heading: the gradient of the headings with respect to dpp_left and T_F is finite."""
    n = 600
    steps = np.where(np.arange(n) < 200, 0.0, 40.0)
    left, right = np.cumsum(steps), np.cumsum(steps * 0.995)
    course = np.cumsum(0.02 * (0.005 * steps) / 1.5)
    d = 0.5 * 0.02 * (steps + 0.995 * steps)
    east, north = np.cumsum(d * np.sin(course + 1.0)), np.cumsum(d * np.cos(course + 1.0))
    nan = np.full(n, math.nan)
    inputs = jm.make_inputs(0.1 * np.arange(n), left, right, nan, nan, fix_east_m=east, fix_north_m=north,
                            fix_valid=(np.arange(n) % 10 == 0).astype(float))
    base = jm.make_params()

    def loss(x):
        out = jm.run(base._replace(dpp_left=x[0], T_F=x[1]), inputs, jm.Config(mode="kalman"))
        return jnp.sum(jnp.sin(out.heading)), out.initialized

    (value, initialized), grad = jax.value_and_grad(loss, has_aux=True)(jnp.asarray([0.02, float(base.T_F)]))
    assert np.asarray(initialized).max() > 0.5
    assert np.all(np.isfinite(np.asarray(grad))), grad


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["urban", "parking"])
def test_kalman_mode_with_fixes_and_no_compass_starts_from_the_fixes(scenario):
    """A matrix drive with no compass (held-out seed 104) in the Kalman mode with its 1-Hz fixes of 4 m: before
    stop 49 the heading never started (urban 2-70 deg, parking 130 deg off for 15 minutes).  Now it starts within
    the first 30 s, its reliability rises from the least, and the RMSE after the first minute is within 1 deg urban,
    3 deg parking (measured 0.36 and 1.80).  Without the fixes it stays unstarted, reliability least."""
    drive = sc.make_drive(scenario, "no_compass", 104)
    out = run_drive(drive, mode="kalman")
    started = np.asarray(out.initialized) > 0.5
    t = drive.truth["time_s"]
    assert started.any() and t[np.argmax(started)] < 30.0
    least = float(reliability_of_bound(jm.make_params(drive.params), UNINITIALIZED_BOUND))
    reliability = np.asarray(out.heading_reliability)
    assert np.allclose(reliability[~started], least) and np.median(reliability[started]) > 2 * least
    assert rmse(after_first_minute(heading_error_deg(out, drive), drive)) < {"urban": 1.0, "parking": 3.0}[scenario]

    no_fixes = dict(drive.columns, fix_valid=np.zeros_like(drive.columns["fix_valid"]))
    blind = run_drive(sc.ScenarioDrive(drive.scenario, drive.condition, drive.seed, no_fixes, drive.truth,
                                       drive.params), mode="kalman")
    assert not (np.asarray(blind.initialized) > 0.5).any()
    assert np.allclose(np.asarray(blind.heading_reliability), least)


_kalman_run = jax.jit(lambda p, i: jm.run(p, i, jm.Config(mode="kalman")))
N = 64
_FIX = st.one_of(st.floats(-2000.0, 2000.0, allow_nan=False),
                 st.sampled_from([math.nan, math.inf, -math.inf, 9.9e6, -9.9e6, 1e7, 1e300, -0.0, 1e-300]))


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.float64, N, elements=_FIX), hnp.arrays(np.float64, N, elements=_FIX),
       hnp.arrays(np.float64, N, elements=st.sampled_from([0.0, 1.0, 1.0, math.nan, 2.0, -1.0])),
       hnp.arrays(np.float64, N, elements=st.integers(-3, 60).map(float)), st.booleans())
def test_no_fix_makes_a_nan_heading_without_a_compass(east, north, valid, steps, on_a_line):
    """No compass at all, the Kalman mode, moving wheels, and fixes that are anything (NaN, inf, 9.9e6 m, scattered
    or on a line along the track): every output finite, the heading wrapped, and started only by a valid fix."""
    t = 0.1 * np.arange(N)
    left = np.cumsum(steps)
    right = np.cumsum(np.roll(steps, 3))
    if on_a_line:  # fixes that follow a straight track, then the drawn values on every 4th sample
        line = 0.02 * np.cumsum(0.5 * (steps + np.roll(steps, 3)))
        east, north = np.where(np.arange(N) % 4 == 0, east, 0.6 * line), np.where(np.arange(N) % 4 == 0, north,
                                                                                   0.8 * line)
    nan = np.full(N, math.nan)
    inputs = jm.make_inputs(t, left, right, nan, nan, fix_east_m=east, fix_north_m=north, fix_valid=valid)
    out = _kalman_run(jm.make_params(), inputs)
    for name in ("heading", "wheel_heading", "x", "y", "speed", "heading_reliability", "heading_bound"):
        value = np.asarray(getattr(out, name))
        assert np.all(np.isfinite(value)), (name, value)
    h = np.asarray(out.heading)
    assert np.all((h > -math.pi) & (h <= math.pi))
    started = np.asarray(out.initialized) > 0.5
    usable = (valid > 0.5) & (np.abs(east) < 1e7) & (np.abs(north) < 1e7)
    if started.any():  # the heading is started on a sample with a usable fix, after at least ALIGN_MIN_FIXES of them
        first = int(np.argmax(started))
        assert usable[first] and np.count_nonzero(usable[:first + 1]) >= FA.ALIGN_MIN_FIXES


@pytest.mark.slow
def test_fixes_realign_a_course_that_an_unknown_tyre_mismatch_spun_off():
    """A 1.5 % tyre mismatch the parameters do not know and no compass (the matrix's urban/mismatch_1.5 drive of
    seed 101 with its compass removed), Kalman mode with fixes: the wheel course turns ~0.6 deg per metre, the
    filter's course runs off, its fixes are rejected, and before stop 49's re-alignment it stayed 100 deg off.  Now
    the fixes re-align the course and release beta: RMSE after the first minute within 3 deg (measured 1.36), and
    while re-aligning the reliability is the least."""
    drive = sc.make_drive("urban", "mismatch_1.5", 101)
    nan = np.full_like(drive.columns["compass_x"], np.nan)
    drive = sc.ScenarioDrive(drive.scenario, drive.condition, drive.seed,
                             dict(drive.columns, compass_x=nan, compass_y=nan), drive.truth, drive.params)
    p = jm.make_params(drive.params)
    out = run_drive(drive, mode="kalman")
    assert rmse(after_first_minute(heading_error_deg(out, drive), drive)) < 3.0
    least = float(reliability_of_bound(p, UNINITIALIZED_BOUND))
    reliability = np.asarray(out.heading_reliability)
    started = np.asarray(out.initialized) > 0.5
    assert started.any() and np.median(reliability[started]) > 2 * least
    assert np.any(np.isclose(reliability[started], least))  # re-aligned at least once: the course was lost
