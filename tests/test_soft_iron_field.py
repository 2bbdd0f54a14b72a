"""The compass's soft-iron deviation read from the field's magnitude per heading (jaxmodel/soft_iron_field.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxmodel import soft_iron as si
from jaxmodel import soft_iron_field as sf


def _readings(e1, e2, headings, field=20.0, noise=0.0, seed=0):
    """The horizontal field of magnitude ``field`` at true raw angles ``headings`` through the symmetric soft iron
    [[1 + e1, e2], [e2, 1 - e1]], with white noise per axis: the measured angle and magnitude."""
    rng = np.random.default_rng(seed)
    s = np.array([[1.0 + e1, e2], [e2, 1.0 - e1]])
    b = field * np.stack([np.cos(headings), np.sin(headings)])
    m = s @ b + rng.normal(0.0, noise, b.shape)
    return np.arctan2(m[1], m[0]), np.hypot(m[0], m[1])


def _learn(angles, magnitudes, d_t=1.0, b_e=None, use=None, reset=None):
    """The state after the samples (numpy arrays), scanned; B_E per heading taken as the sample's own |B| unless
    given (the gate then passes every sample)."""
    n = len(angles)
    b_e = magnitudes if b_e is None else b_e
    use = np.ones(n, bool) if use is None else use
    reset = np.zeros(n, bool) if reset is None else reset

    def body(state, x):
        a, m, e, u, r = x
        return sf.update(state, si.harmonics(a), m, e, jnp.asarray(d_t), u, r), None

    xs = tuple(jnp.asarray(v) for v in (angles, magnitudes, b_e, use, reset))
    return jax.lax.scan(body, sf.init_soft_field_state(), xs)[0]


def _wrapped(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_area_law_the_deviation_is_the_magnitude_conjugate_harmonic():
    """The module's premise, checked on the map itself: for S = [[1 + e1, e2], [e2, 1 - e1]] the measured angle
    turns at det(S) B^2 / |m|^2 (exactly), and to first order (the second, e^2 ~ 1e-3, is the tolerance) the
    deviation phi - A is e2 cos 2 phi - e1 sin 2 phi while ln|m| is ln B + e1 cos 2 phi + e2 sin 2 phi."""
    e1, e2 = 0.03, -0.015
    a = np.linspace(0.0, 2 * np.pi, 2001)
    phi, mag = _readings(e1, e2, a)
    dphi = np.gradient(np.unwrap(phi), a)
    np.testing.assert_allclose(dphi[1:-1], (1 - e1 * e1 - e2 * e2) * 400.0 / mag[1:-1] ** 2, rtol=1e-5)
    deviation = _wrapped(phi - a)
    np.testing.assert_allclose(deviation, e2 * np.cos(2 * phi) - e1 * np.sin(2 * phi), atol=2.5e-3)
    np.testing.assert_allclose(np.log(mag / 20.0), e1 * np.cos(2 * phi) + e2 * np.sin(2 * phi), atol=2.5e-3)


def test_recovers_a_known_soft_iron_from_the_magnitude_alone():
    """A drive through every heading (40 km, 1 m per sample, 0.2 µT of noise per axis on 20 µT): the applied
    deviation matches the true phi - A within 0.3 deg at every heading (95 % of it: the significance threshold takes
    Z0 standard deviations off the amplitude).  Over 4 km the ridge prior and the threshold shrink it (to about
    80 %), never beyond the truth and never turning its sign."""
    e1, e2 = 0.05, 0.03
    grid = np.linspace(-np.pi, np.pi, 73)
    phi_g, _ = _readings(e1, e2, grid)
    true = _wrapped(phi_g - grid)
    for km, (low, high) in ((40, (0.93, 1.01)), (4, (0.6, 1.0))):
        a = np.cumsum(np.full(km * 1000, 2 * np.pi / 400.0))  # a full turn every 400 m
        phi, mag = _readings(e1, e2, a, noise=0.2)
        state = _learn(phi, mag)
        applied = np.asarray(sf.deviation(state, si.harmonics(jnp.asarray(phi_g))))
        share = float(np.dot(applied, true) / np.dot(true, true))
        assert low < share < high, (km, share)
        if km == 40:
            assert np.max(np.abs(np.degrees(applied - true))) < 0.3
            p, q = (float(v) for v in sf.coefficients(state))
            assert p == pytest.approx(-e1, abs=0.003) and q == pytest.approx(e2, abs=0.003)


def test_nothing_is_applied_from_a_narrow_arc_of_headings():
    """A highway seen along one arc (headings within +-40 deg): however strong the magnitude's variation, the
    second harmonic cannot be told from the first (or the terrain), and nothing is applied."""
    a = 0.7 * np.sin(np.linspace(0.0, 30.0, 5000))
    phi, mag = _readings(0.06, 0.0, a, noise=0.05)
    state = _learn(phi, mag)
    assert np.allclose(sf.coefficients(state), 0.0, atol=0.0)


def test_a_round_field_applies_nothing():
    """Without a soft iron the fitted harmonic is noise, below the significance threshold: nothing is applied."""
    a = np.cumsum(np.full(3000, 2 * np.pi / 300.0))
    phi, mag = _readings(0.0, 0.0, a, noise=0.3, seed=3)
    assert np.allclose(sf.coefficients(_learn(phi, mag)), 0.0, atol=0.0)


def test_samples_beyond_the_gate_or_unused_or_standing_teach_nothing():
    """An anomaly (|B| 30 % above B_E per heading), a sample not in use and a sample at standstill leave the sums."""
    a = np.cumsum(np.full(600, 2 * np.pi / 300.0))
    phi, mag = _readings(0.05, 0.0, a, noise=0.1)
    base = _learn(phi, mag)
    for extra in ({"b_e": mag[-1] / 1.3, "use": True}, {"b_e": mag[-1], "use": False}):
        state = sf.update(base, si.harmonics(jnp.asarray(phi[-1])), jnp.asarray(mag[-1]),
                          jnp.asarray(extra["b_e"]), jnp.asarray(1.0), jnp.asarray(extra["use"]), jnp.asarray(False))
        np.testing.assert_array_equal(np.asarray(state.vector), np.asarray(base.vector))
    standing = sf.update(base, si.harmonics(jnp.asarray(phi[-1])), jnp.asarray(mag[-1]),
                         jnp.asarray(mag[-1]), jnp.asarray(0.0), jnp.asarray(True), jnp.asarray(False))
    np.testing.assert_array_equal(np.asarray(standing.vector), np.asarray(base.vector))


def test_a_reset_starts_the_sums_again():
    a = np.cumsum(np.full(600, 2 * np.pi / 300.0))
    phi, mag = _readings(0.05, 0.0, a)
    reset = np.zeros(600, bool)
    reset[400] = True
    state = _learn(phi, mag, reset=reset)
    fresh = _learn(phi[400:], mag[400:])
    np.testing.assert_allclose(np.asarray(state.vector), np.asarray(fresh.vector), rtol=1e-12, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(heading=st.floats(allow_nan=True, allow_infinity=True), b_m=st.floats(allow_nan=True, allow_infinity=True),
       b_e=st.floats(allow_nan=True, allow_infinity=True), d_t=st.floats(0, 1e6), use=st.booleans(),
       reset=st.booleans())
def test_state_stays_finite(heading, b_m, b_e, d_t, use, reset):
    """Anything on a sample not in use leaves the state finite; one in use is finite by the model's construction
    (a valid compass: a finite heading, 1e-9 < |B| < 1e100, B_E > 0)."""
    if use and not (np.isfinite(heading) and abs(heading) < 1e6 and 1e-9 < abs(b_m) < 1e100
                    and 1e-9 < abs(b_e) < 1e100):
        use = False
    a = np.cumsum(np.full(500, 2 * np.pi / 250.0))
    phi, mag = _readings(0.05, 0.02, a, noise=0.1)
    state = sf.update(_learn(phi, mag), si.harmonics(jnp.asarray(heading)),
                      jnp.asarray(abs(b_m)), jnp.asarray(abs(b_e)), jnp.asarray(d_t), jnp.asarray(use),
                      jnp.asarray(reset))
    assert np.all(np.isfinite(np.asarray(state.vector)))
    assert np.all(np.isfinite(np.asarray(sf.deviation(state, si.harmonics(jnp.asarray(1.0))))))


def test_gradients_match_finite_differences():
    a = np.cumsum(np.full(800, 2 * np.pi / 200.0))
    phi, mag = _readings(0.05, 0.02, a, noise=0.1)
    state = _learn(phi, mag)

    def f(heading, b_m, table_p):
        out = sf.update(state, si.harmonics(heading), b_m, jnp.asarray(20.0), jnp.asarray(1.0),
                        jnp.asarray(True), jnp.asarray(False))
        return sf.deviation(out, si.harmonics(heading + 0.3), (table_p, 0.5 * table_p))

    check_grads(f, (jnp.asarray(1.1), jnp.asarray(20.5), jnp.asarray(-0.02)), order=1, modes=["rev", "fwd"],
                rtol=1e-4)
    check_grads(lambda t, o: sf.table_deviation(t, o)[0] + 2.0 * sf.table_deviation(t, o)[1],
                (jnp.linspace(-2.0, 3.0, 36), jnp.asarray(0.4)), order=1, modes=["rev", "fwd"])


@pytest.mark.parametrize("offset_deg", [0.0, 25.0, -130.0])
def test_table_deviation_is_the_tables_second_harmonic_in_the_headings_frame(offset_deg):
    """A table deviation(raw) = amp cos(2 raw - phase) + a first and a third harmonic (neither is soft iron) took
    -amp cos(2 raw - phase) out of H_C; at A = raw + offset that is p_0 sin 2A + q_0 cos 2A exactly."""
    amp, phase, offset = np.radians(3.0), np.radians(40.0), np.radians(offset_deg)
    raw = np.arange(36) * np.radians(10.0)
    table = np.degrees(amp * np.cos(2 * raw - phase) + 0.02 * np.sin(raw) + 0.01 * np.cos(3 * raw))
    p0, q0 = (float(v) for v in sf.table_deviation(jnp.asarray(table), jnp.asarray(offset)))
    a = np.linspace(-np.pi, np.pi, 37)
    np.testing.assert_allclose(p0 * np.sin(2 * a) + q0 * np.cos(2 * a), -amp * np.cos(2 * (a - offset) - phase),
                               atol=1e-12)
    assert sf.table_deviation(jnp.zeros(36), jnp.asarray(offset)) == (0.0, 0.0)


def test_a_calibrated_table_is_not_applied_twice():
    """The field reads the whole soft iron; what the deviation table took out already is not taken out again.  With
    the whole true deviation in the table (40 km through every heading) what is left is under 3 % of it; with half of
    it, the other half is applied (the significance threshold takes a little off)."""
    e1, e2 = 0.05, 0.03
    a = np.cumsum(np.full(40000, 2 * np.pi / 400.0))
    phi, mag = _readings(e1, e2, a, noise=0.2)
    state = _learn(phi, mag)
    whole = (-e1, e2)  # the deviation the field reads (test_recovers_a_known_soft_iron_from_the_magnitude_alone)
    assert np.hypot(*(float(v) for v in sf.coefficients(state, whole))) < 0.03 * np.hypot(e1, e2)
    p, q = (float(v) for v in sf.coefficients(state, (-e1 / 2, e2 / 2)))
    assert p == pytest.approx(-e1 / 2, abs=0.004) and q == pytest.approx(e2 / 2, abs=0.004)
    np.testing.assert_array_equal(np.asarray(sf.coefficients(state, sf.NO_TABLE)), np.asarray(sf.coefficients(state)))
