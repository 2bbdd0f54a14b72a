"""Issue 11: warnings where the result is probably wrong, on stderr (estimate) and in the identify
report: no usable compass, an uncalibrated compass, a counter_modulus that does not match the
counters, a counter that stopped counting, odometer samples that failed the plausibility checks (with their
times); identify keeps a finished fit when a plot fails."""

import json

import numpy as np
import pytest

import jaxmodel as jm
from identification import cli
from identification.diagnostics import batch_warnings
from identification.drive_log import drive_from_columns, write_drive
from identification.scenarios import unwrap_counter
from identification.simulate import simulate


@pytest.fixture(scope="module")
def base():
    cols, truth = simulate("urban", 120.0, seed=5, anomalies=False)
    return cols, truth


def _warnings(cols, params: dict, tmp_path, capsys, name="d.csv", mode="complementary"):
    drive, pfile, est = tmp_path / name, tmp_path / "p.json", tmp_path / "est.csv"
    write_drive(drive, cols)
    pfile.write_text(json.dumps(params))
    before = drive.read_bytes()
    assert cli.main(["estimate", str(drive), "--params", str(pfile), "--out", str(est), "--mode", mode]) == 0
    assert drive.read_bytes() == before
    err = capsys.readouterr().err
    return [line for line in err.splitlines() if line.startswith("odocompass: warning: ")], err


def test_clean_drive_has_no_warning(base, tmp_path, capsys):
    cols, truth = base
    warnings, err = _warnings(dict(cols), dict(truth["params"]), tmp_path, capsys)
    assert warnings == [], err


def test_no_usable_compass(base, tmp_path, capsys):
    cols = dict(base[0], compass_x=np.full_like(base[0]["compass_x"], np.nan))
    warnings, _ = _warnings(cols, dict(base[1]["params"]), tmp_path, capsys)
    assert any("no usable compass" in w and "d.csv" in w and "from the wheels alone" in w for w in warnings), warnings


@pytest.mark.parametrize("value, reason", [(np.nan, "NaN or infinite"), (0.0, "both components exactly 0")])
def test_no_usable_compass_says_why_its_samples_are_invalid(base, tmp_path, capsys, value, reason):
    """A logger that writes 0 for a missing compass (issue 10: all zero) is told so, not 'no field' (stop 53)."""
    cols = dict(base[0], compass_x=np.full_like(base[0]["compass_x"], value),
                compass_y=np.full_like(base[0]["compass_y"], value))
    warnings, _ = _warnings(cols, dict(base[1]["params"]), tmp_path, capsys)
    assert any("no usable compass" in w and reason in w for w in warnings), warnings


def test_no_usable_compass_in_the_compass_mode_says_there_is_no_heading(base, tmp_path, capsys):
    """Before stop 44 the compass mode was told its heading came 'from the wheels alone'."""
    cols = dict(base[0], compass_x=np.full_like(base[0]["compass_x"], np.nan))
    warnings, _ = _warnings(cols, dict(base[1]["params"]), tmp_path, capsys, mode="compass")
    assert any("no usable compass" in w and "no heading to give" in w for w in warnings), warnings
    assert not any("wheels alone" in w for w in warnings), warnings


@pytest.mark.parametrize("mode", ["kalman", "complementary"])
def test_no_usable_compass_with_fixes_says_the_kalman_mode_starts_from_them(tmp_path, capsys, mode):
    """A drive with position fixes and no compass: the Kalman mode starts its heading from the fixes (stop 49,
    jaxmodel/fix_alignment.py) and says so; the default mode, which takes no fixes, points to it."""
    cols, truth = simulate("urban", 120.0, seed=5, anomalies=False, fixes_sigma=4.0)
    cols = dict(cols, compass_x=np.full_like(cols["compass_x"], np.nan))
    warnings, _ = _warnings(cols, dict(truth["params"]), tmp_path, capsys, mode=mode)
    expected = "starts the heading from the position fixes" if mode == "kalman" else "--mode kalman starts the heading"
    assert any("no usable compass" in w and expected in w for w in warnings), warnings


def test_time_in_milliseconds(base, tmp_path, capsys):
    """Before stop 44 a log stamped in milliseconds ran without a word, every speed 1000 x too small."""
    cols = dict(base[0], time_s=np.asarray(base[0]["time_s"]) * 1000.0)
    warnings, _ = _warnings(cols, dict(base[1]["params"]), tmp_path, capsys)
    assert any("milliseconds" in w and "d.csv" in w for w in warnings), warnings


def test_uncalibrated_compass_field_magnitude_and_reference(base, tmp_path, capsys):
    cols, truth = base
    field = float(np.median(np.hypot(cols["compass_x"], cols["compass_y"])))
    bad = dict(cols, compass_x=cols["compass_x"] + 0.6 * field)  # a hard-iron offset nobody removed
    warnings, _ = _warnings(bad, dict(truth["params"], field_magnitude=field), tmp_path, capsys)
    text = "\n".join(warnings)
    assert "uncalibrated" in text and "circles around" in text and "off the reference" in text, text
    assert "field_magnitude" in "\n".join(_warnings(bad, dict(truth["params"], field_magnitude=0.5 * field),
                                                    tmp_path, capsys)[0])
    # with the field learned (field_magnitude 0): the magnitude varying with heading gives it away
    no_ref = {k: v for k, v in bad.items() if k != "ref_heading_deg"}
    warnings, _ = _warnings(no_ref, dict(truth["params"], field_magnitude=0.0), tmp_path, capsys)
    assert any("uncalibrated" in w for w in warnings), warnings


def test_counter_modulus_mismatch_and_dropped_odometer_samples(base, tmp_path, capsys):
    cols, truth = base
    params = dict(truth["params"])
    # counters that wrap at 2**12 while the file says 2**16
    wrapped = dict(cols, left_pulses=np.mod(cols["left_pulses"], 4096), right_pulses=np.mod(cols["right_pulses"], 4096))
    warnings, _ = _warnings(wrapped, params, tmp_path, capsys)
    assert any("counter_modulus 65536 does not match" in w and "wrap near" in w for w in warnings), warnings
    # one counter sample of 1e15: beyond the modulus, failing the plausibility checks at its time (substituted)
    spike = dict(cols, left_pulses=np.asarray(cols["left_pulses"], dtype=np.int64).copy())
    spike["left_pulses"][500] = 10**15
    warnings, _ = _warnings(spike, params, tmp_path, capsys)
    text = "\n".join(warnings)
    assert "reaches 1000000000000000" in text, text
    t500 = f"{cols['time_s'][500]:.1f}"
    assert any("odometer samples failed the plausibility checks" in w and t500 in w and "replaced their motion" in w
               for w in warnings), text


def test_a_wheel_that_stops_counting_is_warned_about_with_its_times(base, tmp_path, capsys):
    """A left wheel sensor stuck for 5 s while moving: one warning naming the counter and the time of the fault."""
    cols, truth = base
    t = np.asarray(cols["time_s"])
    left = unwrap_counter(cols["left_pulses"])  # the counters wrap at 65536
    lost = np.flatnonzero((t >= 60.0) & (t < 65.0))
    assert np.all(np.diff(left)[lost - 1] >= 3)  # the fault is while driving
    # the counter holds its value for 5 s, then counts on from there (the pulses of the 5 s are lost)
    stuck_left = left.copy()
    stuck_left[lost] = left[lost[0] - 1]
    stuck_left[lost[-1] + 1:] -= left[lost[-1]] - left[lost[0] - 1]
    warnings, err = _warnings(dict(cols, left_pulses=stuck_left % 65536), dict(truth["params"]), tmp_path, capsys)
    stopped = [w for w in warnings if "stopped counting" in w]
    assert len(stopped) == 1 and "left_pulses stopped counting while right_pulses counted on" in stopped[0], err
    assert f"t = {t[lost[0]]:.1f}-{t[lost[-1]]:.1f} s" in stopped[0], stopped


def test_identify_report_has_the_drive_warnings_and_survives_a_failed_plot(base, tmp_path, capsys, monkeypatch):
    cols, truth = base
    drive = tmp_path / "nocompass.csv"
    write_drive(drive, dict(cols, compass_y=np.full_like(cols["compass_y"], np.inf)))
    good = tmp_path / "good.csv"
    write_drive(good, cols)
    init = tmp_path / "init.json"
    init.write_text(json.dumps(dict(truth["params"], a=0.0)))
    assert any("no usable compass" in w for w in batch_warnings([drive_from_columns(
        dict(cols, compass_y=np.full_like(cols["compass_y"], np.inf)), source="x")], jm.make_params()))

    from identification import plots

    def broken(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plots, "write_all", broken)
    out = tmp_path / "fit.json"
    rc = cli.main(["identify", str(good), "--params", str(init), "--out", str(out), "--fit", "T_F,a",
                   "--validate", str(drive), "--max-iter", "8", "--plots", str(tmp_path / "plots")])
    err = capsys.readouterr().err
    assert rc == 0, err
    report = json.loads(out.read_text())["report"]
    assert "No space left" in report["plot_error"]
    text = "\n".join(report["warnings"])
    assert "no usable compass" in text and "nocompass.csv" in text
    assert "a starts at 0" in text  # the zero start is allowed, and said
    assert "plots not written" in err and "no usable compass" in err and "\r" not in err
    assert report["parameters"]["a"]["transform"] == "softplus" and report["parameters"]["a"]["fitted"] >= 0.0


def test_identify_warns_of_a_drive_fitted_twice_or_validated_on_itself(tmp_path, monkeypatch):
    """Before stop 44 ``identify d.csv --validate d.csv`` reported a 'held-out' RMSE of a fitted drive silently."""
    from identification.identify_command import _reuse_warnings

    monkeypatch.chdir(tmp_path)
    (tmp_path / "d.csv").write_text("x")
    (tmp_path / "e.csv").write_text("x")
    warnings = _reuse_warnings(["d.csv", "./d.csv", "e.csv"], [str(tmp_path / "d.csv"), "f.csv"])
    assert len(warnings) == 2, warnings
    assert "given twice" in warnings[0] and "./d.csv" in warnings[0]
    assert "also fitted" in warnings[1]
    assert _reuse_warnings(["d.csv"], ["e.csv"]) == []
