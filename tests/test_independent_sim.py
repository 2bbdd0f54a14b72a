"""bench/independent_sim.py, the simulator written without reading the project's own (stop 45): its drives
follow SPEC's conventions as the estimator reads them, and the compass warnings tell hard iron from grades."""

import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import independent_sim as sim  # noqa: E402

import jaxmodel as jm  # noqa: E402
from identification.diagnostics import checked_params, drive_warnings  # noqa: E402
from identification.drive_log import read_drive, wrap_deg  # noqa: E402
from identification.estimate import estimate_drive  # noqa: E402


def _rmse_after_60_s(cols, drive):
    err = wrap_deg(cols["heading_deg"] - np.rad2deg(np.asarray(drive.ref_heading)))
    return float(np.sqrt(np.mean(err[cols["time_s"] >= 60.0] ** 2)))


@pytest.mark.slow
def test_a_clean_drive_agrees_with_the_estimators_conventions(tmp_path):
    """Anomalies, hills, tilt, slip, road noise, soft iron, calibration error and compass noise off: the compass
    alone and the wheels alone both follow the true heading (a sign, axis or unit error would be degrees off)."""
    path, params_path = sim.make_drive("urban", 1, tmp_path, duration=300.0, clean=True, disable=("compass_noise",))
    drive = read_drive(path)
    params, _ = checked_params(params_path)
    rmse = {mode: _rmse_after_60_s(estimate_drive(params, drive, jm.Config(mode=mode)), drive)
            for mode in ("compass", "odometer", "complementary")}
    assert rmse["compass"] < 0.3, rmse  # measured 0.04 deg on 15 minutes
    assert rmse["odometer"] < 2.0 and rmse["complementary"] < 2.0, rmse  # a pulse is 1.4-1.9 deg of heading


def test_the_drive_is_deterministic_and_the_parameter_file_is_valid(tmp_path):
    a = sim.make_drive("highway", 3, tmp_path / "a", duration=120.0)
    b = sim.make_drive("highway", 3, tmp_path / "b", duration=120.0)
    assert Path(a[0]).read_bytes() == Path(b[0]).read_bytes()
    checked_params(a[1])  # raises on an invalid file
    assert {"P", "B", "T_F", "T_R", "a", "dpp_left", "dpp_right"} <= set(json.loads(Path(a[1]).read_text()))


def test_a_vehicle_seed_drives_one_vehicle_on_the_routes_of_other_seeds(tmp_path):
    """``vehicle_seed`` (bench_identify_independent): the vehicle is drawn from it alone, so two routes share it; the
    route, the driver and the start heading stay those of the drive's own seed (its path within a millimetre of the
    drive's without)."""
    vehicle_keys = ("sensor_axle", "P", "B", "T_F", "T_R", "a", "dpp_left", "dpp_right", "counter_modulus")
    drives = {name: sim.make_drive(kind, seed, tmp_path / name, duration=60.0, vehicle_seed=vehicle)
              for name, kind, seed, vehicle in (("own", "urban", 5, None), ("urban", "urban", 5, 7),
                                                ("mixed", "mixed", 6, 7))}
    params = {name: json.loads(Path(p).read_text()) for name, (_, p) in drives.items()}
    assert {k: params["urban"][k] for k in vehicle_keys} == {k: params["mixed"][k] for k in vehicle_keys}
    assert params["urban"]["B"] != params["own"]["B"] and params["urban"]["dpp_left"] != params["own"]["dpp_left"]
    assert Path(drives["urban"][0]).name == "indep_urban_s5_v7.csv"
    truth = {name: np.loadtxt(Path(c).with_suffix(".truth.csv"), delimiter=",", skiprows=1)
             for name, (c, _) in drives.items()}
    header = Path(drives["own"][0]).with_suffix(".truth.csv").read_text().splitlines()[0].split(",")
    xy = [header.index("x_m"), header.index("y_m")]
    # (The vehicle's own slip moves the reference point by micrometres.)
    np.testing.assert_allclose(truth["urban"][:, xy], truth["own"][:, xy], atol=1e-3)
    assert np.max(np.abs(truth["mixed"][:, xy] - truth["own"][:, xy])) > 10.0


def test_a_parameter_file_a_little_off_changes_only_the_right_wheels_dpp(tmp_path):
    _, params_path = sim.make_drive("highway", 3, tmp_path, duration=30.0)
    true = json.loads(Path(params_path).read_text())
    off_path = sim.write_ratio_off_params(params_path, 30.0)
    checked_params(off_path)
    off = json.loads(Path(off_path).read_text())
    assert off["dpp_right"] / off["dpp_left"] == pytest.approx(true["dpp_right"] / true["dpp_left"] * (1 + 30e-6),
                                                                rel=1e-12)
    assert {k: v for k, v in off.items() if k != "dpp_right"} == {k: v for k, v in true.items() if k != "dpp_right"}


def test_a_file_without_the_vehicle_keeps_the_compass_calibration_and_runs_the_nominal_vehicle(tmp_path):
    _, params_path = sim.make_drive("highway", 3, tmp_path, duration=30.0)
    true = json.loads(Path(params_path).read_text())
    bare_path = sim.write_no_vehicle_params(params_path)
    bare = json.loads(Path(bare_path).read_text())
    assert not set(bare) & {*jm.VEHICLE_KEYS, "sensor_axle"}
    assert bare == {k: true[k] for k in sim.NOT_VEHICLE_KEYS}
    params, extra = checked_params(bare_path)
    assert jm.for_unidentified_vehicle(params, extra["keys"])[1]  # odocompass estimate's nominal vehicle


def test_a_file_without_a_learns_the_turn_error_at_speed(tmp_path):
    """bench_independent.py --no-a: the vehicle's own file less a; estimate then runs the speed-scaled turn-scale
    state (jaxmodel.UNKNOWN_VELOCITY_COEFFICIENT) and still counts the vehicle as given."""
    _, params_path = sim.make_drive("highway", 3, tmp_path, duration=30.0)
    true = json.loads(Path(params_path).read_text())
    no_a_path = sim.write_no_a_params(params_path)
    assert json.loads(Path(no_a_path).read_text()) == {k: v for k, v in true.items() if k != "a"}
    params, extra = checked_params(no_a_path)
    learned, nominal = jm.for_unidentified_vehicle(params, extra["keys"])
    assert not nominal
    assert float(learned.filter_scale_speed_ref) == jm.UNKNOWN_VELOCITY_COEFFICIENT["filter_scale_speed_ref"]
    assert float(learned.a) == jm.PARAMETER_SPECS["a"].default != true["a"]


@pytest.mark.slow
def test_grades_are_not_taken_for_hard_iron_but_an_offset_is(tmp_path):
    """Before stop 45 a calibrated compass on 8-9 % grades was called uncalibrated ('the measured horizontal field
    varies from 20.27 to 27.21 with heading', urban_hilly seed 2): the tilt spreads the magnitude per heading.  The
    warning now looks at where the field circle is centred, which an offset moves and the grades hardly do."""
    path, params_path = sim.make_drive("urban_hilly", 2, tmp_path, duration=900.0)
    drive = read_drive(path)
    params, _ = checked_params(params_path)
    cols = estimate_drive(params, drive)
    assert not any("uncalibrated" in w for w in drive_warnings(drive, params, cols)), drive_warnings(drive, params,
                                                                                                      cols)
    for dx, dy in ((6.0, 0.0), (-6.0, 0.0), (0.0, 6.0)):  # the offsets of another car: 6 uT of hard iron left
        warnings = drive_warnings(drive, params._replace(X0=params.X0 + dx, Y0=params.Y0 + dy), cols)
        assert any("uncalibrated" in w and "circles around" in w for w in warnings), (dx, dy, warnings)


@pytest.mark.slow
def test_a_hidden_tyre_mismatch_is_found_and_the_highway_heading_follows_its_residual(tmp_path):
    """40 minutes of highway (seed 1, a diagnosis seed: tyres 1.28 % apart) with both wheels' dpp set to their mean,
    as a user who never measured the mismatch has it: the calibration finds the ratio, and the heading follows the
    calibrated ratio's residual drift (``calibration.corrected``: measured 1.89 deg; 3.98 deg before stop 47, when
    the steady F-DELTA lagged 1.2 deg/km of wheel drift by 6-8 deg for the drive's last 15 km; 1.96 deg with the true
    dpp).  Since stop 59 the default reads |B| as the grade's and the roll's errors (jaxmodel/field_tilt.py), and on
    this drive that is worse, said plainly: 3.45 deg (a 14-µT anomaly 34 minutes in leaves g at -4 to -6 deg while the
    wheels drift, and the heading 6-7 deg off for minutes); the bar of 2.5 deg holds with |B| not read (2.44 deg)."""
    path, params_path = sim.make_drive("highway", 1, tmp_path, duration=2400.0)
    truth = json.loads(Path(params_path).read_text())
    drive = read_drive(path)
    params, _ = checked_params(sim.write_hidden_mismatch_params(params_path))
    cols = estimate_drive(params, drive, jm.Config())
    assert abs(cols["dpp_ratio"][-1] - truth["dpp_right"] / truth["dpp_left"]) < 1e-4, cols["dpp_ratio"][-1]
    assert _rmse_after_60_s(cols, drive) < 4.0
    unread = estimate_drive(params._replace(filter_field_sigma=jnp.asarray(0.0)), drive, jm.Config())
    assert _rmse_after_60_s(unread, drive) < 2.5


@pytest.mark.slow
def test_the_kalman_mode_follows_a_small_hidden_tyre_mismatch(tmp_path):
    """Independent urban seed 24 (tyres 0.09 % apart) with the mismatch hidden from the parameter file: too small a
    drift to be captured as large, it turned the Kalman course 90 deg off over 15 minutes while the compass stayed
    right (58.5 deg RMSE), until beta^ was released to the rate filter's significant rate once the course ran 20 deg
    from the compass (``kalman.released_rate_variance``: 8.0 deg; the complementary mode 2.3 deg)."""
    from independent_drives import heading_error_deg, unidentified_params

    path, params_path = sim.make_drive("urban", 24, tmp_path)
    params = unidentified_params(sim.write_hidden_mismatch_params(params_path))
    t, err = heading_error_deg(path, params, jm.Config(mode="kalman"))
    after_first_minute = t >= 60.0
    rmse = float(np.sqrt(np.mean(err[after_first_minute] ** 2)))
    assert rmse < 12.0, rmse
    assert np.max(np.abs(err[after_first_minute])) < 30.0


def test_the_kalman_mode_takes_the_compass_heading_dependent_error_out(tmp_path):
    """Independent urban seed 62 (a diagnosis drive of stop 90): the compass course after the hard and soft iron is +2
    to +5 deg off for minutes at a time.  The Kalman mode without fixes followed it (4.02 deg RMSE over 10 minutes; the
    default 1.78) until it measured the compass less the grade's and roll's error the robust F-DELTA estimates
    (``model._kalman_compass``) and let dth1 decorrelate over the road (``kf_gm_m``): 1.87 deg."""
    from independent_drives import heading_error_deg, rmse_after_first_minute

    path, params_path = sim.make_drive("urban", 62, tmp_path, duration=600.0)
    params, _ = checked_params(params_path)
    rmse = rmse_after_first_minute(*heading_error_deg(path, params, jm.Config(mode="kalman")))
    assert rmse < 2.8, rmse


def test_the_glitched_copy_adds_three_bursts_and_two_spikes_while_moving(tmp_path):
    """bench_independent.add_glitches (the glitch bar on this simulator's vehicles): the copy's counters differ from
    the drive's by three bursts of 8-40 pulses counted from their sample on and two one-sample spikes of +-3000 counts,
    all after the first minute, wrapped at the counters' modulus; every other column is the drive's."""
    import bench_independent as bi

    path, params_path = sim.make_drive("highway", 3, tmp_path, duration=300.0)
    pj = json.loads(Path(params_path).read_text())
    modulus = pj["counter_modulus"]
    glitched, t_first = bi.add_glitches(path, modulus, 0.5 * (pj["dpp_left"] + pj["dpp_right"]), seed=3)
    names = ("time_s", "left_pulses", "right_pulses", "compass_x", "compass_y", "ref_heading_deg")
    a, b = bi.read_cols(path, names), bi.read_cols(glitched, names)
    for name in ("time_s", "compass_x", "compass_y", "ref_heading_deg"):
        np.testing.assert_array_equal(a[name], b[name])
    bursts, spikes, first = [], [], []
    for wheel in ("left_pulses", "right_pulses"):
        extra = (b[wheel] - a[wheel]) % modulus
        extra = np.where(extra > modulus / 2, extra - modulus, extra)  # the pulses added, signed
        assert np.all((b[wheel] >= 0) & (b[wheel] < modulus))
        change = np.diff(extra, prepend=0.0)
        for i in np.flatnonzero(change):
            first.append(a["time_s"][i])
            if i + 1 < len(change) and change[i + 1] == -change[i]:
                spikes.append(change[i])
            elif i == 0 or change[i - 1] != -change[i]:
                bursts.append(change[i])
    assert len(bursts) == 3 and all(8 <= n <= 40 for n in bursts), bursts
    assert sorted(abs(s) % modulus for s in spikes) in ([3000.0, 3000.0], [modulus - 3000.0] * 2), spikes
    assert min(first) == t_first and t_first >= a["time_s"][0] + 60.0
