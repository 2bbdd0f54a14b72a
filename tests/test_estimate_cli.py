"""``odocompass estimate`` and ``estimate_drive``: the output table, skipped-sample counts, and the
refusal of bad logs and bad parameters (exit 2, one line on stderr, no output file)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxmodel
from identification.cli import main as cli_main
from identification.drive_log import drive_from_columns, read_table, write_drive
from identification.estimate import OUTPUT_COLUMNS, EstimatorBug, estimate_drive

from drives import rear_axle_columns

REPO = Path(__file__).resolve().parents[1]
MODULUS = 65536
N = 160


def drive_columns(n=N, dt=0.1, speed=12.0, turn_rate=0.2, dpp=0.02, track=1.55, field=40.0, seed=0):
    """Rear-axle drive: straight, a right turn of about 90 degrees, straight; counters wrap at 2**16."""
    rng = np.random.default_rng(seed)
    t = 10.0 + dt * np.arange(n) + 0.01 * rng.uniform(-1.0, 1.0, n)
    i = np.arange(n)
    rate = np.where((i > n // 4) & (i <= n // 4 + 40), turn_rate, 0.0)
    return rear_axle_columns(t, rate, speed, dpp, track, field, (65300, 65100), MODULUS)


@pytest.fixture(scope="module")
def rear_params():
    return jaxmodel.make_params(sensor_axle="rear", T_R=1.55, a=0.0)


@pytest.fixture
def params_file(tmp_path):
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"sensor_axle": "rear", "T_R": 1.55, "a": 0.0, "dpp_left": 0.02, "dpp_right": 0.02}))
    return path


def test_a_file_without_the_pulse_scale_says_where_it_comes_from(tmp_path, capsys):
    """A file with the vehicle's geometry but neither dpp: the scale is looked for in the drive's compass
    (wheel_scales); this 16-s drive cannot tell it, and the line says the nominal is kept."""
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"sensor_axle": "rear", "T_R": 1.55, "a": 0.0}))
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns())
    rc, err = run_cli(["estimate", str(drive_path), "--params", str(params), "--out", str(tmp_path / "e.csv")], capsys)
    assert rc == 0, err
    assert "the nominal distance per pulse (0.02 m) kept" in err


def test_estimate_pads_to_a_length_bucket_without_changing_the_drive(rear_params):
    """estimate_drive runs the drive padded to ``bucket_length`` samples and cuts the outputs back: equal to
    jaxmodel.run on the drive itself, and two logs of nearby lengths share one compiled program."""
    import jax
    import jax.numpy as jnp

    from identification.drive_log import bucket_length

    drive = drive_from_columns(drive_columns(n=150), source="short.csv")
    assert bucket_length(150) == bucket_length(157) == 192
    inputs = jaxmodel.Inputs(*(jnp.asarray(np.asarray(v, np.float64)) for v in drive.inputs))
    plain = jax.device_get(jaxmodel.run(rear_params, inputs))
    cols = estimate_drive(rear_params, drive)
    assert len(cols["heading_deg"]) == 150
    np.testing.assert_allclose(np.radians(cols["heading_deg"]), np.angle(np.exp(1j * np.asarray(plain.heading))),
                               rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(cols["x_m"], np.asarray(plain.x), rtol=0.0, atol=1e-9)
    compiled = jaxmodel.run._cache_size()
    estimate_drive(rear_params, drive_from_columns(drive_columns(n=157, seed=1), source="longer.csv"))
    assert jaxmodel.run._cache_size() == compiled  # the same bucket: no new program


def run_cli(argv, capsys):
    rc = cli_main(argv)
    captured = capsys.readouterr()
    return rc, captured.err


def assert_refused(rc, err, out_path, *fragments):
    assert rc == 2, err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    assert lines[0].startswith("odocompass: error: "), err
    for frag in fragments:
        assert str(frag).lower() in lines[0].lower(), (frag, err)
    assert not Path(out_path).exists()
    assert not [p for p in Path(out_path).parent.iterdir() if p.name.startswith(".") and "tmp" in p.name]


# ----------------------------------------------------------------------------------------------
# the library function


def test_estimate_drive_table(rear_params):
    cols = drive_columns()
    drive = drive_from_columns(cols, source="turn")
    table = estimate_drive(rear_params, drive, jaxmodel.Config())
    assert tuple(table) == OUTPUT_COLUMNS
    for k, v in table.items():
        assert isinstance(v, np.ndarray) and v.shape == (N,) and np.all(np.isfinite(v)), k
    np.testing.assert_array_equal(table["time_s"], cols["time_s"])
    for k in ("heading_deg", "wheel_heading_deg", "compass_heading_deg"):
        assert np.all((table[k] > -180.0) & (table[k] <= 180.0)), k
    for k in ("compass_valid", "odometer_valid", "map_used"):
        assert set(np.unique(table[k])) <= {0, 1}, k
    # an exact rear-axle drive with a perfect compass: the estimate follows the turn
    err = (table["heading_deg"] - cols["ref_heading_deg"] + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(err)) < 5.0
    assert table["compass_valid"].sum() == N and table["odometer_valid"][1:].sum() == N - 1
    assert table["effective_track_m"][5] == pytest.approx(1.55)
    # dead-reckoned distance: about speed * duration
    path_len = np.sum(np.hypot(np.diff(table["x_m"]), np.diff(table["y_m"])))
    assert path_len == pytest.approx(12.0 * (cols["time_s"][-1] - cols["time_s"][0]), rel=0.02)


def test_compass_mode_reports_the_compass(rear_params):
    cols = drive_columns()
    table = estimate_drive(rear_params, drive_from_columns(cols), jaxmodel.Config(mode="compass"))
    np.testing.assert_allclose(table["heading_deg"], table["compass_heading_deg"], atol=1e-12)
    err = (table["heading_deg"] - cols["ref_heading_deg"] + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(err)) < 1e-9


def test_non_finite_output_is_reported_as_a_bug(rear_params, monkeypatch):
    drive = drive_from_columns(drive_columns())  # N samples: the compiled run is reused
    real_run = jaxmodel.run

    def broken_run(params, inputs, config=jaxmodel.DEFAULT_CONFIG):
        out = real_run(params, inputs, config)
        return out._replace(heading=out.heading.at[7].set(np.nan))

    monkeypatch.setattr(jaxmodel, "run", broken_run)
    with pytest.raises(EstimatorBug, match=r"heading_deg.*row 8"):
        estimate_drive(rear_params, drive)


_nan_positions = st.lists(st.integers(0, N - 1), max_size=N).map(lambda xs: sorted(set(xs)))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(positions=_nan_positions, which=st.sampled_from(["x", "y", "both", "inf"]),
       mode=st.sampled_from(["complementary", "odometer", "kalman"]))
def test_random_bad_compass_samples_never_give_nan_heading(rear_params, positions, which, mode):
    cols = drive_columns()
    bad = np.asarray(positions, dtype=np.int64)
    if which in ("x", "both"):
        cols["compass_x"][bad] = np.nan
    if which in ("y", "both"):
        cols["compass_y"][bad] = np.nan
    if which == "inf":
        cols["compass_y"][bad] = -np.inf
    drive = drive_from_columns(cols)
    assert drive.metadata["bad_compass_samples"] == len(positions)
    table = estimate_drive(rear_params, drive, jaxmodel.Config(mode=mode))
    for k, v in table.items():
        assert np.all(np.isfinite(v)), k
    assert set(np.flatnonzero(table["compass_valid"] == 0)) == set(positions)


def test_no_usable_compass_at_all(rear_params):
    cols = drive_columns()
    cols["compass_x"][:] = np.nan
    cols["compass_y"][: N // 2] = 0.0           # second half: x NaN, y finite -> still invalid
    cols["compass_x"][: N // 2] = 0.0           # first half: zero field carries no direction
    table = estimate_drive(rear_params, drive_from_columns(cols))
    for k, v in table.items():
        assert np.all(np.isfinite(v)), k
    assert table["compass_valid"].sum() == 0


# ----------------------------------------------------------------------------------------------
# the command line, in process


@pytest.mark.parametrize("fmt", ["csv", "parquet", "mf4"])
def test_estimate_cli_writes_table(tmp_path, params_file, capsys, fmt):
    cols = drive_columns()
    cols["compass_x"][[10, 11, 90]] = np.nan
    drive_path = write_drive(tmp_path / f"drive.{fmt}", cols)
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--params", str(params_file), "--out", str(out)], capsys)
    assert rc == 0, err
    assert "skipped 3 compass samples, 0 odometer samples" in err
    assert len(err.strip().split("\n")) == 1
    header = out.read_text().split("\n", 1)[0].split(",")
    assert header == list(OUTPUT_COLUMNS)
    table = read_table(out)
    assert len(table["time_s"]) == N
    np.testing.assert_array_equal(table["time_s"], cols["time_s"])  # exact through the CSV
    assert np.all(np.isfinite(table["heading_deg"]))
    assert table["compass_valid"].dtype == np.int64 and table["compass_valid"][[10, 11, 90]].tolist() == [0, 0, 0]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([drive_path.name, "est.csv", "params.json"])


@pytest.mark.parametrize("options", [
    ["--mode", "odometer"], ["--mode", "compass"], ["--mode", "kalman"],
    ["--calibration", "off", "--refine-a", "off"], ["--track", "table"], ["--filter", "seed"],
    ["--filter", "robust", "--mode", "odometer"],
])
def test_estimate_cli_options(tmp_path, capsys, options):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns())
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out), *options], capsys)  # default params
    assert rc == 0, err
    table = read_table(out)
    assert np.all(np.isfinite(table["heading_deg"])) and len(table["heading_deg"]) == N


def test_filter_seed_is_the_seed_filter_and_robust_the_default(tmp_path, params_file, capsys):
    """--filter robust (the default) and --filter seed run Config(robust=True / False), nothing else differs."""
    cols = drive_columns()
    drive_path = write_drive(tmp_path / "drive.csv", cols)
    inputs = drive_from_columns(cols).inputs
    params = jaxmodel.make_params(sensor_axle="rear", T_R=1.55, a=0.0)
    for option, robust in ((None, True), ("robust", True), ("seed", False)):
        out = tmp_path / f"est_{option}.csv"
        argv = ["estimate", str(drive_path), "--params", str(params_file), "--out", str(out)]
        rc, err = run_cli(argv + (["--filter", option] if option else []), capsys)
        assert rc == 0, err
        expected = np.degrees(np.asarray(jaxmodel.run(params, inputs, jaxmodel.Config(robust=robust)).heading))
        np.testing.assert_allclose(read_table(out)["heading_deg"], expected, atol=1e-9)


def test_without_vehicle_parameters_the_turn_scale_is_learned(tmp_path, params_file, capsys):
    """The wheel turn's scale not given (no file, or a file without a dpp and a track): the offset filter's
    turn-scale state on (jaxmodel.UNIDENTIFIED_VEHICLE), said on stderr; a file that gives a dpp and a track (or
    the turn-scale keys themselves) runs the parameters as they are.  (This 16-s drive is too short for
    wheel_scales to find the dpp from the compass: the nominal is kept.)"""
    cols = drive_columns()
    drive_path = write_drive(tmp_path / "drive.csv", cols)
    inputs = drive_from_columns(cols).inputs
    filter_only = tmp_path / "filter_only.json"
    filter_only.write_text(json.dumps({"T_C": 900.0}))
    explicit = tmp_path / "explicit.json"
    explicit.write_text(json.dumps({"filter_scale_sigma0": 0.0}))
    cases = ((None, jaxmodel.make_params(jaxmodel.UNIDENTIFIED_VEHICLE), True),
             (filter_only, jaxmodel.make_params(dict(jaxmodel.UNIDENTIFIED_VEHICLE, T_C=900.0)), True),
             (params_file, jaxmodel.make_params(sensor_axle="rear", T_R=1.55, a=0.0), False),
             (explicit, jaxmodel.make_params(), False))
    for path, params, learned in cases:
        out = tmp_path / "est.csv"
        rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)] + (["--params", str(path)] if path else []),
                          capsys)
        assert rc == 0, err
        assert ("error learned online (filter_scale_sigma0" in err) == learned, (path, err)
        expected = np.degrees(np.asarray(jaxmodel.run(params, inputs).heading))
        np.testing.assert_allclose(read_table(out)["heading_deg"], expected, atol=1e-9)


def test_without_a_the_turn_error_at_speed_is_learned(tmp_path, capsys):
    """A file with the dpp and the track but not eq. (8)'s a: the speed-scaled turn-scale state
    (jaxmodel.UNKNOWN_VELOCITY_COEFFICIENT) runs, said on stderr, and nothing else changes."""
    cols = drive_columns()
    drive_path = write_drive(tmp_path / "drive.csv", cols)
    given = {"sensor_axle": "rear", "T_R": 1.55, "dpp_left": 0.02, "dpp_right": 0.02}
    path = tmp_path / "no_a.json"
    path.write_text(json.dumps(given))
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--params", str(path), "--out", str(out)], capsys)
    assert rc == 0, err
    assert "velocity coefficient a of eq. (8) is not given" in err and "filter_scale_sigma0" not in err
    params = jaxmodel.make_params(dict(given, **jaxmodel.UNKNOWN_VELOCITY_COEFFICIENT))
    expected = np.degrees(np.asarray(jaxmodel.run(params, drive_from_columns(cols).inputs).heading))
    np.testing.assert_allclose(read_table(out)["heading_deg"], expected, atol=1e-9)


def test_for_unidentified_vehicle_leaves_given_parameters_alone():
    base = jaxmodel.make_params()
    assert jaxmodel.for_unidentified_vehicle(base, ("T_F", "dpp_left", "a")) == (base, False)
    rear = jaxmodel.make_params(sensor_axle="rear")
    assert jaxmodel.for_unidentified_vehicle(rear, ("T_R", "dpp_left", "dpp_right", "P", "a")) == (rear, False)
    # the scale given but not eq. (8)'s a: the speed-scaled state, and the vehicle still counts as given (stop 83)
    no_a, nominal = jaxmodel.for_unidentified_vehicle(base, ("T_F", "dpp_left", "dpp_right", "P", "B"))
    assert not nominal
    for key, value in jaxmodel.UNKNOWN_VELOCITY_COEFFICIENT.items():
        assert float(getattr(no_a, key)) == value != float(getattr(base, key))
    assert no_a._replace(filter_scale_sigma0=base.filter_scale_sigma0,
                         filter_scale_speed_ref=base.filter_scale_speed_ref) == base
    assert jaxmodel.for_unidentified_vehicle(base, ("T_F", "dpp_left", "filter_scale_speed_ref")) == (base, False)
    # the track of the other axle does not give the sensors' turn scale
    assert jaxmodel.for_unidentified_vehicle(rear, ("T_F", "dpp_left"))[1]
    assert jaxmodel.for_unidentified_vehicle(base, ("T_R", "dpp_left"))[1]
    # the turn's scale is dpp / T_E: a file with only one of them does not give it (stop 81)
    for half in (("T_F", "P", "B"), ("dpp_left", "dpp_right", "a")):
        assert jaxmodel.for_unidentified_vehicle(base, half)[1]
    assert jaxmodel.for_unidentified_vehicle(base, ("filter_scale_psd",)) == (base, False)
    changed, nominal = jaxmodel.for_unidentified_vehicle(base, ("T_C", "D_N"))
    assert nominal and float(changed.filter_scale_sigma0) == jaxmodel.UNIDENTIFIED_VEHICLE["filter_scale_sigma0"]
    assert float(changed.filter_tilt_sigma_deg) == jaxmodel.UNIDENTIFIED_VEHICLE["filter_tilt_sigma_deg"]
    assert float(changed.filter_reject_harden_m) == jaxmodel.UNIDENTIFIED_VEHICLE["filter_reject_harden_m"]
    assert float(changed.filter_reject_harden_m) != float(base.filter_reject_harden_m)
    # A filter constant the file sets is kept, and does not stop the turn-scale state.
    tilted = jaxmodel.make_params(filter_tilt_sigma_deg=4.0)
    changed, nominal = jaxmodel.for_unidentified_vehicle(tilted, ("filter_tilt_sigma_deg",))
    assert nominal and float(changed.filter_tilt_sigma_deg) == 4.0
    assert float(changed.filter_scale_sigma0) == jaxmodel.UNIDENTIFIED_VEHICLE["filter_scale_sigma0"]


def test_estimate_cli_parquet_output(tmp_path, capsys):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns())
    out = tmp_path / "est.parquet"
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)], capsys)
    assert rc == 0, err
    assert list(read_table(out)) == list(OUTPUT_COLUMNS)


def _bad_drive_cases():
    def drop(col):
        return lambda c: c.pop(col)

    def setv(col, row, value):
        def f(c):
            c[col] = c[col].astype(np.float64)
            c[col][row] = value
        return f

    return {
        "missing_column": (drop("compass_x"), ["'compass_x'", "missing"]),
        "non_monotonic_time": (setv("time_s", 12, 0.0), ["row 13", "'time_s'"]),
        "nan_time": (setv("time_s", 5, np.nan), ["row 6", "'time_s'"]),
        "nan_pulses": (setv("right_pulses", 30, np.nan), ["row 31", "'right_pulses'"]),
        "fractional_pulses": (setv("left_pulses", 2, 3.25), ["row 3", "'left_pulses'"]),
        "negative_pulses": (setv("left_pulses", 4, -1.0), ["row 5", "'left_pulses'"]),
        "empty": (lambda c: c.update({k: v[:0] for k, v in c.items()}), ["empty"]),
    }


BAD = _bad_drive_cases()


@pytest.mark.parametrize("fmt", ["csv", "parquet", "mf4"])
@pytest.mark.parametrize("case", list(BAD))
def test_bad_log_exits_2_with_one_line(tmp_path, capsys, fmt, case):
    mutate, fragments = BAD[case]
    cols = drive_columns(n=40)
    mutate(cols)
    drive_path = write_drive(tmp_path / f"bad.{fmt}", cols)
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)], capsys)
    assert_refused(rc, err, out, drive_path, *fragments)


@pytest.mark.parametrize("name,content", [
    ("zero.csv", b""), ("zero.parquet", b""), ("zero.mf4", b""),
    ("corrupt.parquet", b"PAR1 this is not parquet PAR1"), ("corrupt.mf4", b"MDF     4.10    " + b"\xff" * 300),
    ("corrupt.csv", b"\x00\x01\x02\xff\xfe,\n\x00"), ("drive.txt", b"time_s\n0\n"), ("drive", b"time_s\n0\n"),
])
def test_unreadable_log_exits_2_with_one_line(tmp_path, capsys, name, content):
    drive_path = tmp_path / name
    drive_path.write_bytes(content)
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)], capsys)
    assert_refused(rc, err, out, drive_path)


def test_missing_drive_file(tmp_path, capsys):
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(tmp_path / "nothing.csv"), "--out", str(out)], capsys)
    assert_refused(rc, err, out, "nothing.csv", "not found")


@pytest.mark.parametrize("params,fragments", [
    ({"sensor_axle": "rear", "wheelbase": 2.7}, ["'wheelbase'", "unknown"]),
    ({"P": 1.5}, ["P=1.5"]),
    ({"dpp_left": -0.02}, ["dpp_left"]),
    ({"B": "long"}, ["'B'"]),
])
def test_bad_parameters_exit_2_naming_the_key(tmp_path, capsys, params, fragments):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns(n=20))
    pfile = tmp_path / "p.json"
    pfile.write_text(json.dumps(params))
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--params", str(pfile), "--out", str(out)], capsys)
    assert_refused(rc, err, out, "p.json", *fragments)


def test_params_file_not_json(tmp_path, capsys):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns(n=20))
    pfile = tmp_path / "p.json"
    pfile.write_text("{not json")
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--params", str(pfile), "--out", str(out)], capsys)
    assert_refused(rc, err, out, "p.json")


def test_output_with_unknown_extension_or_same_as_input(tmp_path, capsys):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns(n=20))
    out = tmp_path / "est.xlsx"
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)], capsys)
    assert_refused(rc, err, out, "est.xlsx", ".csv")
    before = drive_path.read_bytes()
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(drive_path)], capsys)
    assert rc == 2 and len(err.strip().split("\n")) == 1 and "drive log itself" in err
    assert drive_path.read_bytes() == before


def test_output_in_unwritable_place(tmp_path, capsys):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns())
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out = blocker / "est.csv"  # a folder path through a file
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)], capsys)
    assert rc == 2 and len(err.strip().split("\n")) == 1 and "est.csv" in err, err


def test_estimator_bug_exits_1_without_output(tmp_path, capsys, monkeypatch):
    drive_path = write_drive(tmp_path / "drive.csv", drive_columns())
    real_run = jaxmodel.run

    def broken_run(params, inputs, config=jaxmodel.DEFAULT_CONFIG):
        out = real_run(params, inputs, config)
        return out._replace(x=out.x.at[3].set(np.inf))

    monkeypatch.setattr(jaxmodel, "run", broken_run)
    out = tmp_path / "est.csv"
    rc, err = run_cli(["estimate", str(drive_path), "--out", str(out)], capsys)
    assert rc == 1 and len(err.strip().split("\n")) == 1 and "x_m" in err and "internal error" in err
    assert not out.exists()


# ----------------------------------------------------------------------------------------------
# the installed command, in a subprocess (no traceback, exit code, one stderr line)


def _odocompass():
    exe = Path(sys.executable).parent / "odocompass"
    if exe.exists():
        return [str(exe)]
    return [sys.executable, "-m", "identification.cli"]


def _run(args, cwd):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run(_odocompass() + args, cwd=cwd, capture_output=True, text=True, env=env, timeout=300)


def test_subprocess_bad_logs(tmp_path):
    cols = drive_columns(n=20)
    cols["left_pulses"] = cols["left_pulses"].astype(np.float64)
    cols["left_pulses"][7] = np.nan
    nan_pulses = write_drive(tmp_path / "nan.mf4", cols)
    corrupt = tmp_path / "corrupt.mf4"
    corrupt.write_bytes(b"MDF     4.10    garbage" * 10)
    for drive_path, fragments in ((nan_pulses, ["row 8", "'left_pulses'"]), (corrupt, [])):
        out = tmp_path / "est.csv"
        proc = _run(["estimate", str(drive_path), "--out", str(out)], tmp_path)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip("\n").split("\n")
        assert len(lines) == 1 and str(drive_path) in lines[0], proc.stderr
        for frag in fragments:
            assert frag in lines[0]
        assert not out.exists()


def test_subprocess_nan_compass_is_estimated(tmp_path):
    cols = drive_columns(n=50)
    cols["compass_y"][[0, 1, 25]] = np.nan
    drive_path = write_drive(tmp_path / "drive.parquet", cols)
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"sensor_axle": "rear", "T_R": 1.55}))
    out = tmp_path / "est.csv"
    proc = _run(["estimate", str(drive_path), "--params", str(params), "--out", str(out)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "skipped 3 compass samples, 0 odometer samples" in proc.stderr
    table = read_table(out)
    assert np.all(np.isfinite(table["heading_deg"])) and table["compass_valid"][[0, 1, 25]].tolist() == [0, 0, 0]
