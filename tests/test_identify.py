"""Identification building blocks and the command line: parameter space, loss smoothness, gradient
against finite differences, fit-set parsing, the CLI round trip through ``odocompass estimate``."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from identification import cli
from identification import loss as L
from identification.drive_log import drive_from_columns, read_drive, stack_drives, stack_reference, write_drive
from identification.errors import OdoCompassError
from identification.identify import identify, plan_stages
from identification.simulate import simulate

VEHICLE = dict(P=0.14, B=2.85, T_F=1.60, a=1.4e-4)  # the test's vehicle, not the defaults


@pytest.fixture(scope="module")
def short_drives():
    """Two short simulated drives of the test vehicle (urban and parking), as Drive objects."""
    out = []
    for i, (scenario, duration) in enumerate((("urban", 150.0), ("parking", 100.0))):
        cols, _ = simulate(scenario, duration, seed=40 + i, params=VEHICLE)
        out.append(drive_from_columns(cols, source=f"{scenario}-{40 + i}"))
    return out


def _problem(drives, keys, lag=100, field="wheel_heading", mode="odometer", align=False):
    inputs, mask = stack_drives(drives)
    ref, rmask = stack_reference(drives)
    start = jm.make_params(curvature_window_m=1.0)
    space = L.make_space(keys, start)
    inputs = jax.tree_util.tree_map(jnp.asarray, inputs)
    mask = mask * rmask
    n_eff = L.effective_counts(np.asarray(inputs.time_s), mask, 10.0)
    cfg = jm.Config(mode=mode, calibration=False)
    return L.StageProblem(space, start, inputs, jnp.asarray(ref), jnp.asarray(mask), cfg, field, align, n_eff, lag)


# ---------------------------------------------------------------------------------------------
# parameter space


def test_param_space_round_trip_and_jacobian():
    start = jm.make_params(P=0.2, B=2.9, variation_deg=-3.0, curvature_clip=0.95)
    space = L.make_space(("P", "B", "variation_deg", "curvature_clip", "T_R"), start)
    assert space.transforms == ("logit", "log", "identity", "logit", "log")
    assert space.dim == 5  # the deviation table is fitted as harmonics: tests/test_compass_fit.py
    z0 = np.zeros(space.dim)
    p0 = space.to_params(jnp.asarray(z0), start)
    for k in ("P", "B", "variation_deg", "curvature_clip"):
        assert float(getattr(p0, k)) == pytest.approx(float(getattr(start, k)), rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(space.theta(z0)[:4], [0.2, 2.9, -3.0, 0.95], rtol=1e-12)
    # d theta / d z of the delta method equals the autodiff Jacobian of the transform
    z = np.linspace(-0.7, 0.9, space.dim)
    jac = jax.jacfwd(lambda zz: jnp.concatenate([jnp.atleast_1d(getattr(space.to_params(zz, start), k)).ravel()
                                                 for k in space.keys]))(jnp.asarray(z))
    np.testing.assert_allclose(np.diag(np.asarray(jac)), space.dtheta_dz(z), rtol=1e-10)
    np.testing.assert_allclose(np.concatenate([np.atleast_1d(np.asarray(getattr(space.to_params(jnp.asarray(z), start), k))).ravel()
                                               for k in space.keys]), space.theta(z), rtol=1e-12)
    # the bounded parameter stays bounded however far the optimiser goes
    p_far = space.to_params(jnp.full(space.dim, 60.0), start)
    assert 0.0 < float(p_far.P) <= 1.0 and float(p_far.B) > 0.0


def test_fractions_are_fitted_inside_their_range():
    """Every key validate_params keeps in [0, 1] goes through a sigmoid, so identify cannot write a
    file that estimate refuses."""
    for key in jm.params.FRACTION_KEYS:
        space = L.make_space((key,), jm.make_params())
        assert space.transforms == ("logit",)
        for far in (-60.0, 60.0):
            jm.validate_params(space.to_params(jnp.full(space.dim, far), jm.make_params()))


def test_parse_fit_and_bad_keys():
    assert L.parse_fit(None) == ("P", "B", "T_F", "a", "T_C", "D_N")
    assert L.parse_fit("T_F, a,T_F") == ("T_F", "a")
    with pytest.raises(OdoCompassError, match="unknown parameter key 'T_X'"):
        L.parse_fit("P,T_X")
    with pytest.raises(OdoCompassError, match="sensor_axle"):
        L.parse_fit("sensor_axle")
    with pytest.raises(OdoCompassError, match="positive"):
        L.make_space(("field_magnitude",), jm.make_params())  # 0 = learned; a positive key cannot start at 0


def test_stage_plan_gives_each_parameter_its_heading():
    stages = plan_stages(L.DEFAULT_FIT, "odometer", 30.0)
    assert [(s.name, s.keys, s.field_name, s.mode) for s in stages] == [
        ("wheel", ("P", "B", "T_F", "a", "T_C"), "wheel_heading", "odometer"),
        ("filter", ("D_N",), "heading", "complementary")]
    (one,) = plan_stages(L.DEFAULT_FIT, "complementary", 30.0)
    assert one.keys == L.DEFAULT_FIT and one.field_name == "heading" and one.lag_s == 0.0


# ---------------------------------------------------------------------------------------------
# loss


def test_one_minus_cos_residual_is_smooth_across_pi():
    w = jnp.ones((1, 4))
    for delta in (1e-3, 1e-6):
        e = jnp.array([[math.pi - delta, -math.pi + delta, 0.3, -0.3]])
        r, _ = L.residuals(e, w, align=False)
        np.testing.assert_allclose(np.asarray(r) ** 2, 2.0 * (1.0 - np.cos(np.asarray(e))), rtol=1e-12)
        # the loss and its slope agree on both sides of the wrap point
        g = jax.grad(lambda x: jnp.sum(L.residuals(x, w, False)[0] ** 2))(e)
        assert float(r[0, 0] ** 2) == pytest.approx(float(r[0, 1] ** 2), rel=1e-12)
        assert float(g[0, 0]) == pytest.approx(-float(g[0, 1]), rel=1e-9)
        assert abs(float(g[0, 0])) < 3 * delta


def test_offset_profiling_and_increments_ignore_a_constant_heading_offset():
    rng = np.random.default_rng(0)
    e = jnp.asarray(0.01 * rng.standard_normal((2, 500)))
    w = jnp.ones_like(e)
    for kw in (dict(align=True), dict(align=False, lag=20)):
        r0, w0 = L.residuals(e, w, **kw)
        r1, w1 = L.residuals(jnp.angle(jnp.exp(1j * (e + 2.5))), w, **kw)  # offset beyond pi/2, wraps
        np.testing.assert_array_equal(np.asarray(w0), np.asarray(w1))
        np.testing.assert_allclose(np.asarray(w0 * r0), np.asarray(w1 * r1), atol=1e-12)


def test_loss_gradient_matches_finite_differences(short_drives):
    keys = ("P", "B", "T_F", "a")
    problem = _problem(short_drives, keys)
    z = jnp.asarray([0.3, -0.4, 0.5, 0.2])
    value, grad, hess, _ = L.forward_value_grad_gn(problem)(z)
    v_rev, g_rev = L.reverse_value_grad(problem, checkpoint=True)(z)
    f = jax.jit(problem.objective)
    assert float(value) == pytest.approx(float(f(z)), rel=1e-12)
    np.testing.assert_allclose(np.asarray(grad), np.asarray(g_rev), rtol=1e-9, atol=1e-9)
    h = 1e-5
    fd = np.array([(float(f(z + h * e)) - float(f(z - h * e))) / (2 * h) for e in np.eye(len(keys))])
    np.testing.assert_allclose(np.asarray(grad), fd, rtol=2e-4, atol=1e-4 * np.max(np.abs(fd)))
    assert np.all(np.linalg.eigvalsh(np.asarray(hess)) >= 1.0 - 1e-9)  # GN + prior: positive definite
    # the filter stage: D_N on the absolute complementary heading
    problem_c = _problem(short_drives, ("D_N",), lag=0, field="heading", mode="complementary")
    zc = jnp.asarray([0.2])
    _, grad_c, _, _ = L.forward_value_grad_gn(problem_c)(zc)
    fc = jax.jit(problem_c.objective)
    fd_c = (float(fc(zc + h)) - float(fc(zc - h))) / (2 * h)
    assert float(grad_c[0]) == pytest.approx(fd_c, rel=2e-4, abs=1e-6)
    assert abs(fd_c) > 1e-3  # D_N has signal on the complementary heading


# ---------------------------------------------------------------------------------------------
# library and command line


def test_validation_drives_are_never_fitted(short_drives):
    start = jm.make_params(curvature_window_m=1.0)
    kw = dict(fit="T_F,a", progress=False, max_iter=60)
    fit_a, rep_a = identify(short_drives[:1], start, **kw)
    fit_b, rep_b = identify(short_drives[:1], start, validate_drives=short_drives[1:], **kw)
    for k in ("T_F", "a"):
        assert float(getattr(fit_a, k)) == float(getattr(fit_b, k))
    assert [r["role"] for r in rep_b["drives"]] == ["train", "validate"]
    assert rep_b["drives"][1]["rmse_after_deg"] >= 0.0


def test_cli_identify_writes_a_file_that_estimate_accepts(tmp_path, short_drives, capsys):
    drives = []
    for i, (scenario, duration) in enumerate((("urban", 150.0), ("parking", 100.0))):
        path = tmp_path / f"{scenario}.csv"
        write_drive(path, simulate(scenario, duration, seed=40 + i, params=VEHICLE)[0])
        drives.append(str(path))
    init = tmp_path / "init.json"
    jm.save_params(init, jm.make_params(curvature_window_m=1.0))
    out = tmp_path / "fit.json"
    plots = tmp_path / "plots"
    rc = cli.main(["identify", drives[0], "--params", str(init), "--out", str(out), "--validate", drives[1],
                   "--fit", "T_F,a,D_N", "--plots", str(plots), "--max-iter", "60"])
    assert rc == 0
    captured = capsys.readouterr()
    assert "RMSE before" in captured.out and "T_F" in captured.out
    data = json.loads(out.read_text())
    report = data["report"]
    for key in ("parameters", "correlation", "drives", "iterations", "wall_time_s", "warnings", "stages"):
        assert key in report
    assert set(report["parameters"]) == {"T_F", "a", "D_N"}
    assert report["parameters"]["T_F"]["std_error"] > 0.0
    assert len(report["correlation"]["matrix"]) == 3
    assert {r["role"] for r in report["drives"]} == {"train", "validate"}
    for row in report["drives"]:
        assert math.isfinite(row["rmse_before_deg"]) and math.isfinite(row["rmse_after_deg"])
    assert sorted(p.name for p in plots.iterdir()) == ["effective_track.png", "heading_error.png", "loss.png"]
    # same schema: load_params accepts it, and `odocompass estimate` runs with it
    fitted, extra = jm.load_params(out)
    assert "report" in extra and float(fitted.T_F) == data["T_F"]
    est = tmp_path / "est.csv"
    assert cli.main(["estimate", drives[1], "--params", str(out), "--out", str(est), "--mode", "odometer"]) == 0
    assert est.stat().st_size > 0
    assert read_drive(drives[1]).n_samples > 0


def test_cli_refuses_bad_requests(tmp_path, short_drives, capsys):
    path = tmp_path / "d.csv"
    cols, _ = simulate("urban", 30.0, seed=3, params=VEHICLE)
    write_drive(path, cols)
    init = tmp_path / "init.json"
    jm.save_params(init, jm.make_params())
    assert cli.main(["identify", str(path), "--params", str(init), "--out", str(tmp_path / "f.json"),
                     "--fit", "P,Q"]) == 2
    assert "unknown parameter key 'Q'" in capsys.readouterr().err
    no_ref = {k: v for k, v in cols.items() if k != "ref_heading_deg"}
    path2 = tmp_path / "noref.csv"
    write_drive(path2, no_ref)
    assert cli.main(["identify", str(path2), "--params", str(init), "--out", str(tmp_path / "f.json")]) == 2
    assert "ref_heading_deg" in capsys.readouterr().err
