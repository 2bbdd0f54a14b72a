"""The drive simulator (identification.simulate) and the sensor models (identification.sensors)."""

from __future__ import annotations

import json
import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel
from identification import sensors
from identification.errors import OdoCompassError
from identification.drive_log import drive_from_columns, read_drive, read_table
from identification.simulate import SCENARIOS, max_steering_curvature, simulate, true_params, truth_paths

MODULUS = 65536
DURATIONS = {"urban": 600.0, "highway": 300.0, "mixed": 900.0, "parking": 1800.0}  # each > one counter wrap


def wrap_deg(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def unwrap_counts(c, modulus=MODULUS):
    d = np.diff(np.asarray(c, dtype=np.int64))
    d = d - modulus * np.round(d / modulus).astype(np.int64)
    return np.concatenate([[0], np.cumsum(d)])


def longest_stop_s(t, speed):
    stopped = speed < 0.05
    best, start = 0.0, None
    for i, s in enumerate(stopped):
        if s and start is None:
            start = t[i]
        elif not s and start is not None:
            best, start = max(best, t[i - 1] - start), None
    if start is not None:
        best = max(best, t[-1] - start)
    return best


@pytest.fixture(scope="module")
def drives():
    return {sc: simulate(sc, DURATIONS[sc], seed=7) for sc in SCENARIOS}


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_scenario_produces_valid_drive(drives, scenario):
    cols, truth = drives[scenario]
    t = cols["time_s"]
    n = t.size
    assert n > 0.99 * DURATIONS[scenario] / 0.1
    for name, v in cols.items():
        assert v.shape == (n,), name
        assert np.all(np.isfinite(v)), f"{name} has non-finite values in a default drive"
    dt = np.diff(t)
    assert np.all(dt > 0.0)
    assert 0.09 < np.median(dt) < 0.11 and dt.std() > 1e-4  # 10 Hz, jittered
    assert dt.max() < 0.25

    # integer counters in [0, modulus) that wrap; decoded distance matches the truth
    for side in ("left_pulses", "right_pulses"):
        c = cols[side]
        assert np.issubdtype(c.dtype, np.integer)
        assert c.min() >= 0 and c.max() < MODULUS
        assert np.count_nonzero(np.abs(np.diff(c)) > MODULUS // 2) >= 1, f"{side} never wraps"
    path = np.sum(np.hypot(np.diff(truth["x_m"]), np.diff(truth["y_m"])))
    counted = 0.5 * (np.abs(np.diff(unwrap_counts(cols["left_pulses"]))).sum()
                     + np.abs(np.diff(unwrap_counts(cols["right_pulses"]))).sum()) * 0.02
    assert counted == pytest.approx(path, rel=2e-3)

    # speeds, accelerations, curvature
    v = truth["speed_mps"]
    if scenario == "urban":
        assert v.min() >= 0.0 and v.max() <= 15.0 + 1e-6
        assert longest_stop_s(t, v) > 3.0
    elif scenario == "parking":
        assert v.max() <= 3.0 + 1e-6
        assert longest_stop_s(t, v) > 3.0
        moving = v > 0.05
        assert np.percentile(v[moving], 90) > 1.5
        # reversing into spaces: the counters count down at times
        assert np.any(np.diff(unwrap_counts(cols["left_pulses"])) < 0)
    elif scenario == "highway":
        assert np.percentile(v, 5) >= 20.0 and v.max() <= 36.0 + 1e-6
    else:
        assert v.max() <= 36.0 + 1e-6 and longest_stop_s(t, v) > 3.0
        assert np.mean(v > 22.0) > 0.05 and np.mean((v > 1.0) & (v < 15.0)) > 0.05
    acc = np.diff(v) / dt
    assert np.percentile(np.abs(acc), 99.9) < 3.0
    c_max = sensors.max_curvature(2.7, 1.55)
    assert np.abs(truth["curvature"]).max() <= 0.91 * c_max

    # the drive reads as a valid drive
    drive = drive_from_columns(cols, source=f"sim-{scenario}")
    assert drive.metadata["bad_compass_samples"] == 0
    assert drive.ref_heading is not None
    ref_err = wrap_deg(cols["ref_heading_deg"] - truth["heading_deg"])
    assert 0.05 < np.sqrt(np.mean(ref_err**2)) < 0.3

    # map heading on straight streets only, either direction of a two-way street
    mv = cols["map_valid"] > 0
    if scenario == "parking":
        assert not mv.any()
    else:
        assert 0.3 < mv.mean() < 0.95
        err = wrap_deg(cols["map_heading_deg"][mv] - truth["heading_deg"][mv])
        err = np.minimum(np.abs(err), np.abs(wrap_deg(err + 180.0)))
        assert np.percentile(err, 99) < 2.0
        assert np.all(np.abs(truth["kappa_per_m"][mv]) < 2e-3)


def test_determinism_per_seed():
    a, ta = simulate("mixed", 240.0, seed=3)
    b, tb = simulate("mixed", 240.0, seed=3)
    c, _ = simulate("mixed", 240.0, seed=4)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    np.testing.assert_array_equal(ta["heading_rad"], tb["heading_rad"])
    assert a["time_s"].size != c["time_s"].size or not np.array_equal(a["compass_x"], c["compass_x"])


def test_simulation_is_fast():
    simulate("highway", 60.0, seed=0)  # warm caches
    t0 = time.perf_counter()
    cols, _ = simulate("highway", 2400.0, seed=1)  # 40 minutes, 24,000 samples, ~70 km
    elapsed = time.perf_counter() - t0
    assert cols["time_s"].size > 23_800
    assert elapsed < 2.0, f"40-minute drive took {elapsed:.2f} s"


def _run(cols, truth, mode, **cfg):
    drive = drive_from_columns(cols)
    params = jaxmodel.make_params(truth["params"])
    config = jaxmodel.Config(mode=mode, **cfg)
    out = jaxmodel.run(params, jaxmodel.Inputs(*(jnp.asarray(v) for v in drive.inputs)), config)
    return wrap_deg(np.degrees(np.asarray(out.heading)) - truth["heading_deg"])


@pytest.mark.parametrize("seed", [0, 1])
def test_wheel_model_consistent_with_estimator(seed):
    """Odometer mode with the TRUE parameters integrates the true heading (pulse quantization + slip only)."""
    cols, truth = simulate("urban", 300.0, seed=seed)
    assert truth["n_anomalies"] > 0
    e = _run(cols, truth, "odometer", refine_a=False, calibration=False)
    drift = wrap_deg(e - e[0])  # the odometer mode starts from the first compass sample
    assert np.sqrt(np.mean(drift**2)) < 1.0
    assert np.abs(drift).max() < 2.0
    # the compass alone sees the anomalies
    ec = _run(cols, truth, "compass", refine_a=False, calibration=False)
    anomaly = truth["anomaly_ut"] > 5.0
    assert anomaly.mean() > 0.005
    assert np.sqrt(np.mean(ec[anomaly] ** 2)) > 5.0
    assert np.abs(ec).max() > 10.0
    assert np.sqrt(np.mean(ec[anomaly] ** 2)) > 5.0 * np.sqrt(np.mean(drift[anomaly] ** 2))
    clean = truth["anomaly_ut"] < 0.5
    assert 0.5 < np.sqrt(np.mean(ec[clean] ** 2)) < 5.0


def test_no_anomalies_and_faults():
    cols, truth = simulate("urban", 120.0, seed=2, anomalies=False)
    assert truth["n_anomalies"] == 0 and np.all(truth["anomaly_ut"] == 0.0)
    assert not cols["compass_unreliable_area"].any()
    faulty, _ = simulate("urban", 120.0, seed=2, faults=True)
    bad = ~(np.isfinite(faulty["compass_x"]) & np.isfinite(faulty["compass_y"]))
    assert 1 <= bad.sum() <= 10
    assert drive_from_columns(faulty).metadata["bad_compass_samples"] == bad.sum()


def test_anomalies_flagged_in_part():
    flagged_known = 0
    for seed in range(3):
        cols, truth = simulate("urban", 900.0, seed=seed)
        flag = cols["compass_unreliable_area"] > 0
        strong = truth["anomaly_ut"] > 5.0
        assert flag.any() and strong.any()
        flagged_known += np.count_nonzero(flag & strong)
        # the map knows some anomalies, not all
        assert np.count_nonzero(strong & ~flag) > 0
    assert flagged_known > 0


def test_dpp_mismatch_fewer_right_pulses():
    r = 0.004
    a, _ = simulate("urban", 300.0, seed=5)
    b, tb = simulate("urban", 300.0, seed=5, dpp_mismatch=r)
    np.testing.assert_array_equal(a["left_pulses"], b["left_pulses"])
    na = unwrap_counts(a["right_pulses"])[-1]
    nb = unwrap_counts(b["right_pulses"])[-1]
    assert nb / na == pytest.approx(1.0 / (1.0 + r), abs=2e-5)
    assert tb["true_dpp_right"] == pytest.approx(0.02 * (1 + r))
    assert tb["params"]["dpp_right"] == 0.02  # the parameter file still says dpp_right


def test_params_and_fixes():
    params = {"sensor_axle": "rear", "T_R": 1.6, "dpp_left": 0.018, "dpp_right": 0.018, "X0": 3.0, "Y0": -2.0,
              "rotation_deg": 4.0, "variation_deg": 2.5, "field_magnitude": 18.0, "counter_modulus": 32768}
    cols, truth = simulate("mixed", 400.0, seed=1, params=params, fixes_sigma=3.0)
    assert truth["params"]["sensor_axle"] == "rear" and truth["params"]["T_R"] == 1.6
    assert cols["left_pulses"].max() < 32768
    fv = cols["fix_valid"] > 0
    assert 0.08 < fv.mean() < 0.105  # 1 Hz of 10 Hz, a few outages
    e = np.hypot(cols["fix_east_m"][fv] - truth["x_m"][fv], cols["fix_north_m"][fv] - truth["y_m"][fv])
    assert 1.5 < np.sqrt(np.mean(e**2) / 2.0) < 6.0
    assert np.all(cols["fix_east_m"][~fv] == 0.0)
    # hard iron, rotation and variation are what the estimator removes with these parameters
    b = np.hypot(cols["compass_x"] - 3.0, cols["compass_y"] + 2.0)
    assert np.median(b) == pytest.approx(18.0, rel=0.05)
    e_odo = _run(cols, truth, "odometer", refine_a=False, calibration=False)
    assert np.sqrt(np.mean(wrap_deg(e_odo - e_odo[0]) ** 2)) < 2.0
    e_c = _run(cols, truth, "compass", refine_a=False, calibration=False)
    assert abs(np.median(e_c)) < 1.0
    with pytest.raises(jaxmodel.ParameterError, match="bogus"):
        simulate("urban", 10.0, seed=0, params={"bogus": 1.0})


def _fix_errors(fixes_model):
    """Per-axis errors of the valid fixes of one 30-minute drive (east and north stacked), and their
    lag-1 (1 s) and lag-10 correlations over the fixes taken one second apart."""
    cols, truth = simulate("highway", 1800.0, seed=3, fixes_sigma=4.0, fixes_model=fixes_model)
    assert truth["fixes_model"] == fixes_model and truth["fixes_sigma"] == 4.0
    fv = np.flatnonzero(cols["fix_valid"] > 0)
    errors = [cols[k][fv] - truth[t][fv] for k, t in (("fix_east_m", "x_m"), ("fix_north_m", "y_m"))]
    t = truth["time_s"][fv]

    def corr(lag):
        pairs = [(e[:-lag], e[lag:]) for e in errors]
        ok = np.abs(t[lag:] - t[:-lag] - lag) < 0.2  # no outage between the two fixes
        a = np.concatenate([p[0][ok] for p in pairs])
        b = np.concatenate([p[1][ok] for p in pairs])
        return float(np.corrcoef(a, b)[0, 1])

    return np.concatenate(errors), corr(1), corr(10)


def test_fix_error_models():
    """gnss: sigma per axis, half of the variance correlated over 30 s (correlation at lag 10 s
    0.5 exp(-1/3) = 0.36); white: sigma per axis, uncorrelated.  About 3600 pairs (two axes pooled),
    so the sample correlation of white errors is within +-0.05 (3 sigma); the bound is 0.06.  Both
    models draw the same outages."""
    e, c1, c10 = _fix_errors("gnss")
    assert np.std(e) == pytest.approx(4.0, rel=0.15)
    assert 0.35 < c1 < 0.65 and 0.15 < c10 < 0.55
    e, c1, c10 = _fix_errors("white")
    assert np.std(e) == pytest.approx(4.0, rel=0.05)
    assert abs(c1) < 0.06 and abs(c10) < 0.06
    gnss, _ = simulate("urban", 300.0, seed=5, fixes_sigma=4.0)
    white, _ = simulate("urban", 300.0, seed=5, fixes_sigma=4.0, fixes_model="white")
    np.testing.assert_array_equal(gnss["fix_valid"], white["fix_valid"])
    assert not np.array_equal(gnss["fix_east_m"], white["fix_east_m"])
    with pytest.raises(OdoCompassError, match="unknown fixes model 'colored'"):
        simulate("urban", 10.0, seed=0, fixes_sigma=4.0, fixes_model="colored")


def test_cli_writes_drive_and_truth(tmp_path):
    from identification.cli import main

    out = tmp_path / "drive.csv"
    pfile = tmp_path / "true.json"
    jaxmodel.save_params(pfile, jaxmodel.make_params({"a": 2e-4}))
    rc = main(["simulate", "--scenario", "urban", "--duration", "120", "--seed", "4", "--out", str(out),
               "--params", str(pfile), "--fixes-sigma", "2", "--fixes-model", "white", "--dpp-mismatch", "0.003"])
    assert rc == 0
    csv_path, json_path = truth_paths(out)
    assert csv_path.name == "drive.truth.csv" and json_path.name == "drive.truth.json"
    drive = read_drive(out)
    assert drive.metadata["n_samples"] > 1000
    table = read_table(csv_path)
    for col in ("time_s", "heading_deg", "x_m", "y_m", "speed_mps", "curvature"):
        assert col in table
    np.testing.assert_allclose(table["time_s"], np.asarray(drive.inputs.time_s), atol=1e-6)
    meta = json.loads(json_path.read_text())
    assert meta["scenario"] == "urban" and meta["seed"] == 4 and meta["duration_s"] == 120.0
    assert meta["dpp_mismatch"] == 0.003 and meta["params"]["a"] == 2e-4
    assert meta["fixes_sigma"] == 2.0 and meta["fixes_model"] == "white"
    ref = np.degrees(drive.ref_heading)
    assert np.sqrt(np.mean(wrap_deg(ref - table["heading_deg"]) ** 2)) < 0.3
    assert main(["simulate", "--scenario", "urban", "--duration", "0", "--out", str(out)]) == 2
    assert main(["simulate", "--scenario", "urban", "--duration", "60", "--fixes-model", "white",
                 "--out", str(tmp_path / "nofix.csv")]) == 2
    assert not (tmp_path / "nofix.csv").exists()


# ------------------------------------------------------------------------------------------------
# sensors.py


def test_sensors_has_no_project_imports():
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(sensors))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, "relative import in sensors.py"
            names.add(node.module.split(".")[0])
    assert names <= {"__future__", "math", "dataclasses", "numpy"}


def test_compass_reading_inverts_fig_8a():
    from jaxmodel.compass import compass_heading

    dev = 2.0 * np.sin(np.radians(np.arange(36) * 10.0 * 2) + 0.3)
    p = {"X0": 4.0, "Y0": -1.5, "rotation_deg": 7.0, "variation_deg": -3.0, "deviation_deg": dev}
    params = jaxmodel.make_params(p)
    heading = np.linspace(-math.pi, math.pi, 721)[1:]
    cx, cy = sensors.compass_reading(heading, horizontal=19.0, **p)
    h_c, b_m, ok = jax.vmap(compass_heading, in_axes=(None, 0, 0))(params, jnp.asarray(cx), jnp.asarray(cy))
    assert bool(np.all(ok))
    np.testing.assert_allclose(wrap_deg(np.degrees(np.asarray(h_c) - heading)), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(b_m), 19.0, rtol=1e-12)
    # dip error: pitching the nose up heading east turns the compass and changes |B|
    cx, cy = sensors.compass_reading(math.pi / 2, pitch=math.radians(3.0), horizontal=20.0)
    err = math.degrees(math.atan2(cy, cx)) - 90.0
    assert 4.0 < abs(err) < 8.0  # 40 µT vertical x sin 3° = 2.1 µT across 20 µT
    cx, cy = sensors.compass_reading(0.0, pitch=math.radians(3.0), horizontal=20.0)
    assert abs(math.atan2(cy, cx)) < 1e-12 and math.hypot(cx, cy) < 19.0


def test_differential_distance_inverts_eq_8_and_14():
    from jaxmodel.track import effective_track, wheel_heading_change

    P, B, T_F, a = 0.125, 2.7, 1.55, 1e-4
    AD = np.array([0.1, 1.0, 2.5, 0.3, -0.2])
    dt = np.full(5, 0.1)
    kappa = np.array([0.15, -0.05, 0.002, -0.17, 0.1])
    dD, c = sensors.differential_distance(kappa * AD, AD, dt, P=P, B=B, T_F=T_F, T_R=1.5, a=a)
    T = effective_track(jnp.asarray(c), P, B, T_F)
    back = wheel_heading_change(jnp.asarray(dD), T, a, jnp.asarray(np.abs(AD) / dt))
    np.testing.assert_allclose(np.asarray(back), kappa * AD, rtol=1e-12)
    assert np.all(np.abs(c) < 0.97 * sensors.max_curvature(B, T_F))
    assert max_steering_curvature(true_params()) == pytest.approx(0.19, abs=0.01)  # R_min ~ 5.3 m


def test_anomaly_field_tiles_are_deterministic():
    f1 = sensors.AnomalyField(density_per_km2=60.0, seed=11)
    f2 = sensors.AnomalyField(density_per_km2=60.0, seed=11)
    x = np.linspace(-2000, 2000, 4001)
    y = 0.3 * x
    d1 = f1.disturbance(x, y)
    d2 = f2.disturbance(x[::-1], y[::-1])[::-1]  # order of evaluation does not matter
    np.testing.assert_allclose(d1, d2, atol=1e-12)
    mag = np.linalg.norm(d1[:, :2], axis=1)
    assert 0.02 < np.mean(mag > 1.0) < 0.8 and mag.max() < 40.0


def test_sensor_model_steps_an_ackerman_vehicle():
    """An FMU-style loop: kinematic Ackerman vehicle (steering angle, speed) -> SensorModel.step."""

    def drive(seed):
        model = sensors.SensorModel(seed, dpp_left=0.02, dpp_right=0.02, anomaly_density_per_km2=30.0,
                                    transient_rate_per_s=0.02, counter_offsets=(65000, 100))
        x = y = heading = 0.0
        dl = dr = 0.0
        track, base = 1.55, 2.7
        rows = []
        for k in range(3000):  # 300 s at 10 Hz
            dt = 0.1
            speed = 8.0
            steer = 0.15 * math.sin(2 * math.pi * k / 600.0)  # rad
            kappa = math.tan(steer) / base
            ds = speed * dt
            heading += kappa * ds
            x += ds * math.sin(heading)
            y += ds * math.cos(heading)
            dl += ds * (1 + 0.5 * kappa * track)
            dr += ds * (1 - 0.5 * kappa * track)
            s = model.step(dt, x, y, heading, dl, dr, pitch=0.0)
            rows.append((s.left_pulses, s.right_pulses, s.compass_x, s.compass_y, heading, dl, s.unreliable_area))
        return np.array(rows, dtype=np.float64)

    a = drive(5)
    b = drive(5)
    c = drive(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[:, 2], c[:, 2])
    left = a[:, 0].astype(np.int64)
    assert left.min() >= 0 and left.max() < MODULUS and np.any(np.diff(left) < -30000)  # wrapped
    assert unwrap_counts(left)[-1] * 0.02 == pytest.approx(a[-1, 5], rel=1e-3)
    err = wrap_deg(np.degrees(np.arctan2(a[:, 3], a[:, 2]) - a[:, 4]))
    assert np.median(np.abs(err)) < 3.0
