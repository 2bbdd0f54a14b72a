"""US 4,788,645 eq. (8) and (14): reference values worked from the seed, table vs closed form, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxmodel import track

P, B, T_F = 0.125, 2.7, 1.55

# Worked by hand from eq. (14) with P = 1/8, B = 2.7 m, T_F = 1.55 m: (2B/T_F)^2 = 12.137357.
# c = 0.2: q = 0.04/0.99 x 12.137357 = 0.490398, sqrt(1-q) = 0.713864,
#          sqrt(0.5 + 0.5 x 0.713864) = 0.925706, T_E = 1.55 (0.125 + 0.875 x 0.925706) = 1.449239.
REFERENCE = [
    (0.0, 1.55),
    (0.1, 1.528533076265807),
    (0.2, 1.4492390387367506),
    (0.27, 1.2931759751049838),
]
C_MAX = 0.284125801857672  # 1/sqrt((2B/T_F)^2 + 0.25): the inner square root vanishes
T_E_AT_CLIP = 1.2447144758136817  # eq. (14) at 0.98 c_max


@pytest.mark.parametrize("c, expected", REFERENCE)
def test_effective_track_reference_values(c, expected):
    assert float(track.effective_track(c, P, B, T_F)) == pytest.approx(expected, rel=1e-12)
    assert float(track.effective_track(-c, P, B, T_F)) == pytest.approx(expected, rel=1e-12)


def test_max_curvature():
    assert float(track.max_curvature(B, T_F)) == pytest.approx(C_MAX, rel=1e-12)


@pytest.mark.parametrize("c", [0.2785, 0.3, 1.0, 1e6])
def test_beyond_the_clip_is_finite_and_clipped(c):
    value = track.effective_track(c, P, B, T_F)
    assert float(value) == pytest.approx(T_E_AT_CLIP, rel=1e-12)
    grads = jax.grad(lambda p, b, t: track.effective_track(c, p, b, t), argnums=(0, 1, 2))(P, B, T_F)
    assert all(np.isfinite(float(g)) for g in grads)


def test_gradient_finite_at_zero_and_at_the_geometric_maximum():
    for c in (0.0, C_MAX, C_MAX * 1.0000001):
        g = jax.grad(lambda c_: track.effective_track(c_, P, B, T_F, clip_fraction=0.999999))(c)
        assert np.isfinite(float(g))


def test_table_agrees_with_closed_form_within_1e_6():
    table = track.effective_track_table(P, B, T_F)
    c = jnp.linspace(-0.4, 0.4, 20001)
    closed = track.effective_track(c, P, B, T_F)
    looked_up = track.effective_track_lookup(c, table)
    assert float(jnp.max(jnp.abs(looked_up / closed - 1.0))) < 1e-6


@pytest.mark.parametrize("params", [(0.125, 2.7, 1.55), (0.3, 3.2, 1.7), (0.05, 2.4, 1.45)])
def test_table_agrees_for_other_vehicles(params):
    table = track.effective_track_table(*params)
    c = jnp.linspace(0.0, 0.35, 5001)
    rel = jnp.abs(track.effective_track_lookup(c, table) / track.effective_track(c, *params) - 1.0)
    assert float(jnp.max(rel)) < 1e-6


def test_table_is_differentiable_in_P_B_T_F():
    def via_table(p, b, t):
        return track.effective_track_lookup(0.15, track.effective_track_table(p, b, t))

    check_grads(via_table, (P, B, T_F), order=1, modes=["rev"], eps=1e-6, atol=1e-6, rtol=1e-4)
    g_table = jax.grad(via_table, argnums=(0, 1, 2))(P, B, T_F)
    g_closed = jax.grad(lambda p, b, t: track.effective_track(0.15, p, b, t), argnums=(0, 1, 2))(P, B, T_F)
    np.testing.assert_allclose(np.array(g_table), np.array(g_closed), rtol=1e-3)


def test_closed_form_gradients_match_finite_differences():
    check_grads(lambda p, b, t: track.effective_track(0.2, p, b, t), (P, B, T_F), order=2, eps=1e-6)


def test_wheel_heading_change_eq8():
    # dD = 0.3 m, T = 1.55 m, a = 1e-4 s^2/m^2, V = 20 m/s: 0.3 / (1.55 x 1.04) = 0.186104 rad
    assert float(track.wheel_heading_change(0.3, 1.55, 1e-4, 20.0)) == pytest.approx(0.18610421836228286, rel=1e-12)
    # a = 0 reduces to eq. (7): dD / T
    assert float(track.wheel_heading_change(0.3, 1.5, 0.0, 20.0)) == pytest.approx(0.2, rel=1e-12)
