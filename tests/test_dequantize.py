"""The wheel heading between pulses (jaxmodel/dequantize.py): the counts' quantization out of the heading output."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

import jaxmodel as jm
from jaxmodel import dequantize as dq

PULSE = 0.02 / 1.6  # rad of heading per pulse of dD (2-cm pulses, 1.6-m track)


def _run_filter(alphas, dts, moving=None, pulse=PULSE, restart_first=True):
    """epsilon after each sample of a sequence of wheel turns (numpy arrays)."""
    moving = np.ones_like(alphas, bool) if moving is None else moving
    ds = dq.init_dequant_state()
    out = []
    for k, (a, dt, m) in enumerate(zip(alphas, dts, moving)):
        ds, e = dq.update(ds, jnp.asarray(a), jnp.asarray(dt), jnp.asarray(m), jnp.asarray(pulse),
                          jnp.asarray(restart_first and k == 0))
        out.append(float(e))
    return np.asarray(out)


def _quantized_turn(n=600, dt=0.1, rate=0.05, seed=0):
    """A steady turn at ``rate`` rad/s counted by two wheels with random pulse phases: (true heading, H_W)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    truth = rate * t
    # dD in pulses: the true differential travel plus each wheel's own quantization (phases moving at speed).
    true_pulses = truth / PULSE
    left_phase = rng.uniform(0, 1, n)
    right_phase = rng.uniform(0, 1, n)
    counted = np.floor(true_pulses + left_phase) - np.floor(right_phase)
    return truth, counted * PULSE


def test_quantization_flicker_is_smoothed():
    """A steady turn counted in whole pulses: H_W is off by the quantization (~PULSE / sqrt(6) RMS); H_W + epsilon
    by about 0.63 of that once the filter has the turn rate (iid pulse phases, the worst case for a smoother)."""
    truth, hw = _quantized_turn()
    alphas = np.diff(np.concatenate([[hw[0]], hw]))
    eps = _run_filter(alphas, np.full(hw.size, 0.1))
    late = slice(100, None)
    raw = np.sqrt(np.mean((hw - truth - np.mean(hw - truth))[late] ** 2))
    smoothed_err = hw + eps - truth
    smoothed = np.sqrt(np.mean((smoothed_err - np.mean(smoothed_err[late]))[late] ** 2))
    assert raw == pytest.approx(PULSE / np.sqrt(6.0), rel=0.25)
    assert smoothed < 0.75 * raw, (raw, smoothed)


def test_standing_still_does_not_turn():
    """A car that stops after turning: the filter's turn rate is not extrapolated while standing."""
    truth, hw = _quantized_turn(n=200)
    alphas = np.concatenate([np.diff(np.concatenate([[hw[0]], hw])), np.zeros(300)])
    moving = np.concatenate([np.ones(200, bool), np.zeros(300, bool)])
    eps = _run_filter(alphas, np.full(alphas.size, 0.1), moving)
    assert np.all(np.abs(eps[200:]) <= dq.DEQUANT_MAX_PULSES * PULSE + 1e-15)
    assert abs(eps[-1] - eps[205]) < 0.5 * PULSE


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-3.0, 3.0), st.floats(0.0, 1e6), st.booleans()), min_size=1, max_size=40))
def test_epsilon_never_beyond_its_bound(samples):
    """Whatever the wheel turns and time steps (turns of radians, gaps of days), epsilon stays finite and within
    DEQUANT_MAX_PULSES pulses of wheel heading: it never takes a counted turn away."""
    alphas, dts, moving = (np.asarray(v) for v in zip(*samples))
    eps = _run_filter(alphas, dts, moving)
    assert np.all(np.isfinite(eps))
    assert np.all(np.abs(eps) <= dq.DEQUANT_MAX_PULSES * PULSE * (1 + 1e-12))


def test_gap_restarts_the_filter():
    """A time step beyond DEQUANT_HORIZON_S (a logger that stopped) restarts it: epsilon 0, prior covariance."""
    truth, hw = _quantized_turn(n=100)
    alphas = np.diff(np.concatenate([[hw[0]], hw]))
    dts = np.full(alphas.size, 0.1)
    dts[60] = dq.DEQUANT_HORIZON_S * 10
    ds = dq.init_dequant_state()
    for k in range(61):
        ds, e = dq.update(ds, alphas[k], dts[k], True, PULSE, k == 0)
    f = ds.fields()
    assert float(e) == 0.0 and float(f.omega) == 0.0
    assert float(f.p11) == pytest.approx(dq.DEQUANT_RATE_SIGMA0 ** 2)


def test_gradient_matches_finite_differences():
    """The update is differentiable in the turn and the pulse size (identification runs through it)."""
    ds = dq.DequantState.pack(dq.DequantFields(*(jnp.asarray(v) for v in (0.002, 0.03, 1e-5, 1e-6, 1e-3))))

    def f(alpha, pulse):
        new, e = dq.update(ds, alpha, jnp.asarray(0.1), jnp.asarray(True), pulse, jnp.asarray(False))
        return e + new.omega

    check_grads(f, (jnp.asarray(0.004), jnp.asarray(PULSE)), order=1, modes=["rev"], eps=1e-7)


@pytest.mark.slow
def test_matrix_drive_heading_better_and_wheel_heading_unchanged():
    """highway/baseline/101 of the matrix: the default's heading RMSE after the first minute falls with the filter
    (measured 0.47 -> 0.40 deg), the wheel heading output (H_W as counted) is the same, and the compass-only mode is
    untouched."""
    from identification import scenario_eval as ev
    from identification import scenarios as sc

    drive = sc.make_drive("highway", "baseline", 101)
    params = ev.stack_params([drive.params])
    _, no_fix, mask, truth, time = ev.stacked_inputs([drive])
    keep = (mask > 0.5) & (time - time[:, :1] >= ev.SKIP_S)

    def rmse(out):
        return float(np.degrees(np.sqrt(np.mean(ev._wrapped(np.asarray(out.heading) - truth)[keep] ** 2))))

    on = ev.run_config(params, no_fix, {})
    off = ev.run_config(params, no_fix, {"dequantize": False})
    assert rmse(on) < rmse(off) - 0.04, (rmse(on), rmse(off))
    np.testing.assert_array_equal(np.asarray(on.wheel_heading), np.asarray(off.wheel_heading))
    cmp_on = ev.run_config(params, no_fix, {"mode": "compass"})
    cmp_off = ev.run_config(params, no_fix, {"mode": "compass", "dequantize": False})
    np.testing.assert_array_equal(np.asarray(cmp_on.heading), np.asarray(cmp_off.heading))
    # The heading output never leaves the undequantized one by more than DEQUANT_MAX_PULSES pulses.
    pulse = drive.params["dpp_left"] / float(np.min(np.asarray(on.effective_track)[mask > 0.5]))
    gap = np.abs(ev._wrapped(np.asarray(on.heading) - np.asarray(off.heading)))[mask > 0.5]
    assert gap.max() <= dq.DEQUANT_MAX_PULSES * pulse * (1 + 1e-3)  # the calibration moves dpp by < 1e-3


def test_seed_filter_untouched():
    """robust=False (the seed filter, the oracle's reference) has no dequantization."""
    p = jm.make_params()
    n = 50
    t = np.arange(n) * 0.1
    inputs = jm.make_inputs(t, np.arange(n) * 40.0, np.arange(n) * 41.0, np.full(n, 20.0), np.zeros(n))
    a = jm.run(p, inputs, jm.Config(robust=False))
    b = jm.run(p, inputs, jm.Config(robust=False, dequantize=False))
    np.testing.assert_array_equal(np.asarray(a.heading), np.asarray(b.heading))
