"""The estimator as a whole: FIG. 8 flow by hand, wrapping, counters, seed model, gradients, batching."""

import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

sys.path.insert(0, str(Path(__file__).parent))
import jaxmodel as jm  # noqa: E402
from drives import city_blocks, seed_model_drive  # noqa: E402
from oracle import run_reference  # noqa: E402

PLAIN = jm.Config(refine_a=False, calibration=False, robust=False)
"""The seed's filter (US 4,734,863 FIG. 8 as written), which the hand-worked values and the literal oracle transcribe."""
SEED = jm.Config(robust=False)


def inputs_of(d, **extra):
    return jm.make_inputs(d["time_s"], d["left_pulses"], d["right_pulses"], d["compass_x"], d["compass_y"], **extra)


def wrapped_error(a, b):
    return np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))


def compass_at(angle, field=20.0):
    return field * math.cos(angle), field * math.sin(angle)


def test_three_samples_of_the_fig8_flow_by_hand():
    p = jm.make_params(sensor_axle="rear", T_R=1.5, a=0.0, D_N=100.0, field_magnitude=20.0,
                       F_update_distance_m=1000.0)
    cx, cy = zip(compass_at(0.0), compass_at(0.2), compass_at(0.3))
    inp = jm.make_inputs([0.0, 1.0, 2.0], [0, 500, 1010], [0, 500, 990], cx, cy)
    out = jm.run(p, inp, PLAIN)
    # s1: D_L = D_R = 10 m -> alpha = 0; DELTA = 0.2; start-up gain = 10/10 = 1 -> F-DELTA = 0.2, EH = 0.2
    # s2: D_L = 10.2, D_R = 9.8 -> dD = 0.4, AD = 10, alpha = 0.4/1.5 (eq. 8, a = 0) = 0.266667
    #     DELTA = 0.3 - 0.266667 = 0.033333; gain = max(10 x 1/100, 10/20) = 0.5
    #     F-DELTA = 0.2 + 0.5 (0.033333 - 0.2) = 0.116667; EH = 0.266667 + 0.116667 = 0.383333
    np.testing.assert_allclose(out.wheel_heading, [0.0, 0.0, 0.4 / 1.5], atol=1e-12)
    np.testing.assert_allclose(out.f_delta, [0.0, 0.2, 0.2 + 0.5 * (0.3 - 0.4 / 1.5 - 0.2)], atol=1e-12)
    np.testing.assert_allclose(out.heading, [0.0, 0.2, 0.4 / 1.5 + 0.2 + 0.5 * (0.3 - 0.4 / 1.5 - 0.2)], atol=1e-12)
    # FIG. 8D: E_W = (0 + |0.266667 x 0.1|) (1 - 10/100) = 0.024
    np.testing.assert_allclose(out.e_w[2], 0.4 / 1.5 * 0.1 * 0.9, atol=1e-12)
    # FIG. 8C: |B| = B_E -> E_C is the 1 deg floor
    np.testing.assert_allclose(out.e_c, math.radians(1.0), atol=1e-12)
    # position with the mid-sample heading: s1 moves 10 m at 0.1 rad
    np.testing.assert_allclose([out.x[1], out.y[1]], [10 * math.sin(0.1), 10 * math.cos(0.1)], atol=1e-12)
    np.testing.assert_allclose(out.speed[1:], [10.0, 10.0], atol=1e-12)


def test_fig8e_factor_by_hand():
    from jaxmodel import heading_filter as hf

    p = jm.make_params(heading_error_K=100.0, K1=2.0, K2=4.0)
    # E_h = 0.1 x 100 x (0.05 - 0.02) = 0.3 > 0: F = (0.3 + 2)/2 = 1.15
    assert float(hf.time_constant_factor(p, 0.1, 0.05, 0.02)) == pytest.approx(1.15)
    # E_h = 0.1 x 100 x (0.02 - 0.05) = -0.3: F = 4/(0.3 + 4) (|E_h|, see the docstring)
    assert float(hf.time_constant_factor(p, 0.1, 0.02, 0.05)) == pytest.approx(4 / 4.3)
    # FIG. 8E/A: SD_N of (0.1, 0.2, 0.3) = 0.0816497; SDD = max(SD_N, SD_N/6 + 5/6 x 0.2) = 0.180275
    sd_n = float(hf.deviation_of_three(jnp.array([0.3, 0.2, 0.1])))
    assert sd_n == pytest.approx(math.sqrt(2 / 3) * 0.1)
    assert float(hf.update_sdd(p, 0.2, sd_n)) == pytest.approx(sd_n / 6 + 5 / 6 * 0.2)
    assert float(hf.update_sdd(p, 0.01, sd_n)) == pytest.approx(sd_n)  # fast attack


def test_matches_the_literal_oracle_on_a_city_drive():
    pd = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(), pd, compass_noise_deg=2.0, seed=3)
    ours = np.asarray(jm.run(jm.make_params(), inputs_of(d), PLAIN).heading)
    ref = run_reference(pd, d["time_s"], d["left_pulses"], d["right_pulses"], d["compass_x"], d["compass_y"])
    assert np.max(np.abs(wrapped_error(ours, ref))) < 1e-9


def test_due_south_never_jumps():
    pd = jm.params_to_dict(jm.make_params())
    # drive due south (pi) with compass noise straddling +-pi
    d = seed_model_drive([(3000.0, 0.0, 15.0)], pd, heading0=math.pi, compass_noise_deg=3.0, seed=1)
    # The robust default settles more slowly: it reads a disagreement of its first few hundred metres
    # as possibly the compass's coloured error (filter_gm_m), so it is within 1.5 deg after 900 m, not 450 m.
    for config, settled in ((SEED, 300), (jm.DEFAULT_CONFIG, 600)):
        _assert_due_south(jm.run(jm.make_params(), inputs_of(d), config), settled)


def _assert_due_south(out, settled):
    h = np.asarray(out.heading)
    assert np.all((h > -math.pi) & (h <= math.pi))
    assert np.max(np.abs(wrapped_error(h, math.pi))) < math.radians(6.0)
    assert np.max(np.abs(wrapped_error(h[1:], h[:-1]))) < math.radians(6.0)
    assert np.max(np.abs(wrapped_error(h[settled:], math.pi))) < math.radians(1.5)


def test_counter_wrap_gives_identical_output():
    base = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(), base, seed=2)
    big = jm.make_params(counter_modulus=2.0**40)
    small = jm.make_params(counter_modulus=1000.0)
    unwrapped = inputs_of(d)
    wrapped = unwrapped._replace(left_pulses=unwrapped.left_pulses % 1000.0, right_pulses=unwrapped.right_pulses % 1000.0)
    assert int(np.sum(np.diff(np.asarray(wrapped.left_pulses)) < 0)) > 5  # it really wraps
    a = jm.run(big, unwrapped)
    b = jm.run(small, wrapped)
    np.testing.assert_allclose(a.heading, b.heading, atol=1e-12)
    np.testing.assert_allclose(a.x, b.x, atol=1e-9)


@pytest.mark.parametrize("axle", ["front", "rear"])
def test_constant_curvature_reproduces_the_seed_model(axle):
    pd = jm.params_to_dict(jm.make_params(sensor_axle=axle, dpp_left=1e-4, dpp_right=1e-4, counter_modulus=2.0**40))
    radius, speed = 12.0, 8.0
    d = seed_model_drive([(2 * math.pi * radius * 3, 1.0 / radius, speed)], pd)
    # robust=False: the drive starts at full speed and turn rate, which the odometer guard (robust)
    # cannot tell from a glitch until it has seen GUARD_MAX_SUBSTITUTED samples; eq. (14) is the subject here.
    out = jm.run(jm.make_params(pd), inputs_of(d),
                 jm.Config(mode="odometer", refine_a=False, calibration=False, robust=False))
    err = wrapped_error(out.wheel_heading, d["true_heading"])
    assert np.max(np.abs(err)) < math.radians(0.05)  # three full circles
    if axle == "front":
        c_true = float(np.median(np.asarray(out.curvature)[100:]))
        from oracle import effective_track

        te = effective_track(c_true, pd["P"], pd["B"], pd["T_F"])
        np.testing.assert_allclose(np.asarray(out.effective_track)[100:], te, rtol=1e-4)
        assert te < 0.99 * pd["T_F"]  # a real Ackerman effect at R = 12 m


def test_gradients_of_a_heading_loss_match_finite_differences():
    pd = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(n_blocks=8, radius=10.0), pd, compass_noise_deg=2.0, seed=4)
    inputs = inputs_of(d)
    truth = jnp.asarray(d["true_heading"])
    names = ("P", "B", "T_F", "a", "T_C", "D_N")
    scale = jnp.array([0.125, 2.7, 1.55, 1e-4, 3000.0, 400.0])
    # a off the truth so refinement acts and T_C matters; D_N short enough for this 2 km drive that
    # the nominal gain D_T F / D_N exceeds the start-up floor (docs/design.md)
    base = jm.make_params(a=1.3e-4, T_C=3000.0, D_N=400.0)

    def loss(u):  # u: relative parameter values (1 = nominal), so FD steps are well scaled
        values = u * scale
        p = base._replace(**{n: values[i] for i, n in enumerate(names)})
        out = jm.run(p, inputs, jm.Config(calibration=False, robust=False))
        return jnp.mean(1.0 - jnp.cos(out.heading - truth)) + jnp.mean(1.0 - jnp.cos(out.wheel_heading - truth))

    u0 = jnp.array([1.0, 1.0, 1.0, 1.3, 1.0, 1.0])
    g = jax.grad(loss)(u0)
    assert np.all(np.isfinite(np.asarray(g)))
    assert np.all(np.asarray(g) != 0.0), dict(zip(names, np.asarray(g)))  # every parameter has signal here
    check_grads(loss, (u0,), order=1, modes=["rev"], eps=1e-5, atol=1e-9, rtol=2e-3)


def test_gradients_of_the_default_filter_match_finite_differences():
    """The robust default (Kalman F-DELTA, guard, B_E per heading) is differentiable in the vehicle and filter constants."""
    pd = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(n_blocks=8, radius=10.0), pd, compass_noise_deg=2.0, seed=4)
    inputs = inputs_of(d)
    truth = jnp.asarray(d["true_heading"])
    names = ("P", "B", "T_F", "a", "filter_offset_psd", "filter_compass_sigma_deg", "filter_gm_m")
    scale = jnp.array([0.125, 2.7, 1.55, 1e-4, 3.9e-8, 3.0, 240.0])
    base = jm.make_params(a=1.3e-4)

    def loss(u):
        values = u * scale
        p = base._replace(**{n: values[i] for i, n in enumerate(names)})
        out = jm.run(p, inputs, jm.Config(calibration=False))
        return jnp.mean(1.0 - jnp.cos(out.heading - truth))

    u0 = jnp.array([1.0, 1.0, 1.0, 1.3, 1.0, 1.0, 1.0])
    g = jax.grad(loss)(u0)
    assert np.all(np.isfinite(np.asarray(g))) and np.all(np.asarray(g) != 0.0), dict(zip(names, np.asarray(g)))
    # Central differences per constant with a step of 1e-6: a step of 1e-5 in T_F crosses a gate's
    # kink of the steady F-DELTA on this drive (the difference moves by 0.8 %; at 1e-6 and 1e-7 it
    # equals the gradient to 1e-8), and check_grads' random projection mixes T_F into every check.
    for i, name in enumerate(names):
        e = jnp.zeros_like(u0).at[i].set(1e-6)
        fd = (loss(u0 + e) - loss(u0 - e)) / 2e-6
        np.testing.assert_allclose(g[i], fd, rtol=2e-3, atol=1e-12, err_msg=name)


def test_jit_vmap_run_equals_a_loop_of_run():
    pd = jm.params_to_dict(jm.make_params())
    drives = [seed_model_drive(city_blocks(n_blocks=3, block=50.0 + 20 * k), pd, compass_noise_deg=1.0, seed=k)
              for k in range(3)]
    n = min(len(d["time_s"]) for d in drives)
    batch = jax.tree_util.tree_map(lambda *xs: jnp.stack([x[:n] for x in xs]), *[inputs_of(d) for d in drives])
    p = jm.make_params()
    batched = jax.jit(jax.vmap(jm.run, in_axes=(None, 0)))(p, batch)
    also = jm.run_batch(p, batch)
    for k, d in enumerate(drives):
        single = jm.run(p, jax.tree_util.tree_map(lambda x: x[:n], inputs_of(d)))
        # Equal to rounding: XLA may fuse the batched and the single step's scalar algebra in a different
        # order (1e-18 m apart in x since the offset filter's covariance is unrolled at trace time).
        np.testing.assert_allclose(np.asarray(batched.heading[k]), np.asarray(single.heading), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(also.x[k]), np.asarray(single.x), rtol=1e-12, atol=1e-12)


def test_step_equals_run():
    pd = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(n_blocks=2, block=30.0), pd, compass_noise_deg=1.0)
    inputs = inputs_of(d)
    p = jm.make_params()
    full = jm.run(p, inputs)
    state = jm.init_state(p)
    step = jax.jit(jm.step)
    for i in range(len(d["time_s"])):
        state, out = step(p, state, jax.tree_util.tree_map(lambda x: x[i], inputs))
        assert float(out.heading) == pytest.approx(float(full.heading[i]), abs=1e-12)


def test_table_and_closed_form_paths_agree_on_a_drive():
    pd = jm.params_to_dict(jm.make_params())
    d = seed_model_drive(city_blocks(radius=8.0), pd, compass_noise_deg=1.0)
    p = jm.make_params()
    a = jm.run(p, inputs_of(d), jm.Config(track="closed_form"))
    b = jm.run(p, inputs_of(d), jm.Config(track="table"))
    np.testing.assert_allclose(a.effective_track, b.effective_track, rtol=1e-6)
    assert np.max(np.abs(wrapped_error(a.heading, b.heading))) < 1e-5


def test_float32_parameters_are_refused_without_x64():
    with jax.enable_x64(False):
        with pytest.raises(jm.ParameterError, match="64-bit"):
            jm.make_params()


def test_unknown_parameter_key_is_named():
    with pytest.raises(jm.ParameterError, match="'wheelbase'"):
        jm.make_params({"wheelbase": 2.7})


@pytest.mark.parametrize("bad, name", [(dict(P=1.0), "P"), (dict(B=0.0), "B"), (dict(T_F=-1.0), "T_F"),
                                       (dict(T_R=0.0), "T_R")])
def test_invalid_parameters_are_named(bad, name):
    with pytest.raises(jm.ParameterError, match=name):
        jm.validate_params(jm.make_params(bad))
    with pytest.raises(jm.ParameterError, match="sensor_axle"):
        jm.make_params(sensor_axle="middle")


@pytest.mark.parametrize("key", jm.params.POSITIVE_KEYS)
def test_every_positive_parameter_is_checked(key):
    """Time constants, lengths and divisors: 0 is refused with the key named (a negative Kalman
    time constant used to run and return positions of 1e218 m)."""
    with pytest.raises(jm.ParameterError, match=f"{key}=0.0 must be positive"):
        jm.validate_params(jm.make_params({key: 0.0}))


@pytest.mark.parametrize("key", jm.params.NON_NEGATIVE_KEYS)
def test_every_non_negative_parameter_is_checked(key):
    jm.validate_params(jm.make_params({key: 0.0}))  # zero switches an effect off: allowed
    with pytest.raises(jm.ParameterError, match=f"{key}=-1.0 must not be negative"):
        jm.validate_params(jm.make_params({key: -1.0}))


@pytest.mark.parametrize("key", jm.params.FRACTION_KEYS)
def test_fractions_are_checked(key):
    with pytest.raises(jm.ParameterError, match=rf"{key}=1.5 must be in \[0, 1\]"):
        jm.validate_params(jm.make_params({key: 1.5}))


def test_refinement_speed_band_must_not_be_inverted():
    with pytest.raises(jm.ParameterError, match="refine_speed_min=30.0 above refine_speed_max"):
        jm.validate_params(jm.make_params(refine_speed_min=30.0, refine_speed_max=10.0))
