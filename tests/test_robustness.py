"""Properties: no input (NaN, inf, zero field, counter jumps, zero or negative time steps) makes a
NaN heading or a crash; wrapping properties of the angle helpers."""

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
from jaxmodel.angles import sin_polynomial, wrap
from jaxmodel.packed import computed_once, value_once

N = 48
SPECIAL = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e300, -1e300, 1e-300])
_run_all = {m: jax.jit(lambda p, i, m=m: jm.run(p, i, jm.Config(mode=m))) for m in jm.MODES}


def _floats(special_rate):
    normal = st.floats(-100.0, 100.0, allow_nan=False)
    return st.one_of(normal, SPECIAL) if special_rate else normal


@st.composite
def hostile_drives(draw):
    dt = draw(hnp.arrays(np.float64, N, elements=st.one_of(st.floats(-1.0, 2.0), SPECIAL)))
    t = np.cumsum(np.nan_to_num(dt, nan=0.1, posinf=0.1, neginf=-0.1))
    t[draw(hnp.arrays(np.bool_, N))] = np.nan if draw(st.booleans()) else 0.0
    steps_l = draw(hnp.arrays(np.float64, N, elements=st.one_of(st.integers(-50, 500).map(float), SPECIAL)))
    steps_r = draw(hnp.arrays(np.float64, N, elements=st.one_of(st.integers(-50, 500).map(float), SPECIAL)))
    left = np.cumsum(np.nan_to_num(steps_l, nan=0.0, posinf=1e9, neginf=-1e9))
    right = np.cumsum(np.nan_to_num(steps_r, nan=0.0, posinf=1e9, neginf=-1e9))
    left[np.isnan(steps_l)] = np.nan
    right[np.isinf(steps_r)] = np.inf
    cx = draw(hnp.arrays(np.float64, N, elements=_floats(True)))
    cy = draw(hnp.arrays(np.float64, N, elements=_floats(True)))
    mh = draw(hnp.arrays(np.float64, N, elements=_floats(True)))
    flags = draw(hnp.arrays(np.float64, N, elements=st.sampled_from([0.0, 1.0, math.nan])))
    return jm.make_inputs(t, left, right, cx, cy, map_heading=mh, map_valid=flags, compass_unreliable_area=flags,
                          fix_east_m=cx * 10, fix_north_m=cy * 10, fix_valid=flags)


@settings(max_examples=40, deadline=None)
@given(hostile_drives(), st.sampled_from(jm.MODES))
def test_no_input_makes_a_nan_heading(inputs, mode):
    out = _run_all[mode](jm.make_params(), inputs)
    for name in ("heading", "wheel_heading", "compass_heading", "x", "y", "speed", "a", "heading_reliability",
                 "dpp_ratio", "effective_track", "curvature"):
        value = np.asarray(getattr(out, name))
        assert np.all(np.isfinite(value)), (name, value)
    h = np.asarray(out.heading)
    assert np.all((h > -math.pi) & (h <= math.pi))


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_lands_in_half_open_interval_and_preserves_the_angle(angle):
    w = float(wrap(jnp.float64(angle)))
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(angle), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(angle), abs_tol=1e-9)


def test_wrap_of_pi_is_pi_and_gradient_is_one():
    assert float(wrap(jnp.float64(math.pi))) == math.pi
    assert float(wrap(jnp.float64(-math.pi))) == math.pi
    assert float(jax.grad(wrap)(3.0)) == 1.0
    assert float(jax.grad(wrap)(7.0)) == 1.0


def test_gradient_through_hostile_samples_stays_finite():
    t = np.arange(N) * 0.1
    left = np.cumsum(np.full(N, 40.0))
    right = np.cumsum(np.full(N, 38.0))
    cx = np.full(N, 20.0)
    cy = np.zeros(N)
    cx[5] = np.nan
    cx[9] = 0.0
    cy[9] = 0.0
    left[20] = np.nan
    t[30] = t[29]
    inputs = jm.make_inputs(t, left, right, cx, cy)

    def loss(a, P):
        return jnp.sum(jm.run(jm.make_params()._replace(a=a, P=P), inputs).heading ** 2)

    g = jax.grad(loss, argnums=(0, 1))(jnp.float64(1e-4), jnp.float64(0.125))
    assert all(np.isfinite(float(x)) for x in g)


def test_regression_huge_time_jump_and_huge_field_in_every_mode():
    """Found by hypothesis: time jumping to 1e300 s and a 1e300 compass component (Kalman blew up,
    |B|^2 overflowed)."""
    t = np.r_[0.0, np.ones(33), np.full(14, 1e300)]
    right = np.r_[np.zeros(33), np.ones(15)]
    for cy in (np.full(N, 1e300), np.zeros(N)):
        inputs = jm.make_inputs(t, np.cumsum(np.full(N, 30.0)), right, np.full(N, 20.0), cy)
        for mode in jm.MODES:
            out = _run_all[mode](jm.make_params(), inputs)
            assert np.all(np.isfinite(np.asarray(out.heading))), mode
            assert np.all(np.isfinite(np.asarray(out.x))) and np.all(np.isfinite(np.asarray(out.y))), mode


def test_regression_clock_jump_after_a_turn_keeps_the_heading_wrapped_in_every_mode():
    """Found by hypothesis (stop 21's local database): 26 pulses on one wheel in 1 s, then the clock jumps to
    1e300 s and stays.  The guard extrapolated the recent turn rate over the gap (1e300 s x 0.26 m/s) and
    the wheel heading went 4e282 rad, out of (-pi, pi] for the rest of the drive; a gap beyond
    plausibility.GUARD_HORIZON_S now predicts nothing."""
    t = np.r_[1.0, 2.0, 3.0, 4.0, np.full(N - 4, 1e300)]
    right = np.r_[0.0, 0.0, 0.0, np.full(N - 3, 26.0)]
    z = np.zeros(N)
    inputs = jm.make_inputs(t, z, right, z, z, map_heading=z, map_valid=z, compass_unreliable_area=z,
                            fix_east_m=z, fix_north_m=z, fix_valid=z)
    for mode in jm.MODES:
        out = _run_all[mode](jm.make_params(), inputs)
        h = np.asarray(out.heading)
        assert np.all(np.isfinite(h)) and np.all((h > -math.pi) & (h <= math.pi)), (mode, h)
        for name in ("wheel_heading", "x", "y"):
            assert np.all(np.isfinite(np.asarray(getattr(out, name)))), (mode, name)
        assert np.all(np.abs(np.asarray(out.x)) < 1e3), mode  # no motion invented across the gap


@pytest.mark.parametrize("map_heading", [1e300, -1e300, 1e17, 2e4])
def test_regression_huge_map_heading_is_no_heading_in_every_mode(map_heading):
    """Found by hypothesis (CI of stop 47, under the suite's XLA flags): a 1e300 rad map heading, valid, in a
    compass-unreliable area, at a standstill then one pulse.  wrap(1e300) is rounding noise of any size, the
    selector took it as the street and the Kalman course measurement made the heading -3.9e230 rad."""
    z = np.zeros(N)
    one = np.ones(N)
    pulses = np.r_[z[:-1], 1.0]
    inputs = jm.make_inputs(z, pulses, pulses, z, one, map_heading=np.full(N, map_heading), map_valid=one,
                            compass_unreliable_area=one, fix_east_m=z, fix_north_m=one * 10, fix_valid=one)
    for mode in jm.MODES:
        out = _run_all[mode](jm.make_params(), inputs)
        h = np.asarray(out.heading)
        assert np.all(np.isfinite(h)) and np.all((h > -math.pi) & (h <= math.pi)), (mode, h)
        assert np.allclose(h, math.pi / 2, atol=1e-6), (mode, h)  # the compass's north, no map heading


@settings(max_examples=300, deadline=None)
@given(st.floats(-100.0, 100.0, allow_nan=False))
def test_sin_polynomial_is_sin(angle):
    """angles.sin_polynomial (the tilt gain's sine, a polynomial so that XLA:CPU does not repeat a libm call in
    every kernel) equals sin to rounding for angles of a few turns (its argument is a difference of wrapped
    headings; beyond, the reduction by wrap loses |angle| x 1e-16)."""
    assert abs(float(sin_polynomial(jnp.float64(angle))) - math.sin(angle)) < 1e-13


def test_sin_polynomial_gradient_is_cos():
    for angle in (-3.0, -1.6, -0.2, 0.0, 0.7, 1.5708, 2.9, 40.0):
        assert float(jax.grad(sin_polynomial)(angle)) == pytest.approx(math.cos(angle), abs=1e-12)
    check_grads(sin_polynomial, (jnp.float64(0.4),), order=2, modes=["fwd", "rev"])


def test_computed_once_keeps_the_flag():
    flags = jnp.array([True, False, True])
    np.testing.assert_array_equal(np.asarray(computed_once(flags)), np.asarray(flags))
    assert bool(jax.jit(computed_once)(jnp.bool_(True))) and not bool(jax.jit(computed_once)(jnp.bool_(False)))


SUBNORMAL = [5e-324, -5e-324, 1e-310, -2.2250738585072e-308]


def _assert_same_bits(out, values):
    np.testing.assert_array_equal(out.view(np.int64)[~np.isnan(values)], values.view(np.int64)[~np.isnan(values)])
    assert np.isnan(out[np.isnan(values)]).all()


@given(hnp.arrays(np.float64, 5, elements=st.one_of(st.floats(allow_nan=False), SPECIAL, st.sampled_from(SUBNORMAL))))
@settings(max_examples=50, deadline=None)
def test_value_once_is_the_value_bit_for_bit(values):
    _assert_same_bits(np.asarray(jax.jit(value_once)(jnp.asarray(values))), values)


def test_value_once_keeps_subnormals_jitted_and_eager():
    # CI found 5e-324 flushed to 0.0 by the float maximum of stop 76 (the suite's XLA flags run denormals off); the
    # integer maximum of the bits keeps them.
    values = np.array(SUBNORMAL + [-0.0, math.nan, -math.inf])
    _assert_same_bits(np.asarray(jax.jit(value_once)(jnp.asarray(values))), values)
    _assert_same_bits(np.asarray(value_once(jnp.asarray(values))), values)


def test_value_once_passes_the_gradient_and_none_from_a_masked_nan():
    check_grads(lambda v: value_once(v) ** 3 * jnp.sin(v), (jnp.array([0.3, -1.2, 0.0]),), order=2, modes=["fwd", "rev"])
    # A double-where masks a NaN on the branch not taken; a maximum's own gradient would divide by the count of
    # elements equal to it (none, for a NaN) and put the NaN back into the cotangent.
    x = jnp.array([1.5, jnp.nan, -2.0])
    grad = jax.grad(lambda v: jnp.sum(jnp.where(jnp.isfinite(v), value_once(jnp.where(jnp.isfinite(v), v, 0.0)), 0.0)
                                      + jnp.where(jnp.isfinite(v), 0.0, value_once(v) * 0.0)))(x)
    np.testing.assert_array_equal(np.asarray(grad), [1.0, 0.0, 1.0])
