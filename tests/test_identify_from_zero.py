"""Issue 11: ``odocompass identify`` started from a file with ``a`` = 0 (the datasheet value when
nobody measured it) fits ``a`` in softplus space and recovers the vehicle.

The bar itself (T_F within 0.5 %, a within 10 % after 40 minutes of mixed, urban and parking driving, default fit
set) is ``bench/bench_identify.py --start-a 0``; it took 446 s of the suite on its own (stop 71), so the suite runs
this 7-minute version: the same command line, from a = 0, with T_F to the issue's 0.5 % and a to its standard error
(as the fleet test, tests/test_fleet.py, does for four vehicles through `fleet identify`).  Measured (stop 71):
T_F +0.37 %, a 1.91e-4 against 3.0e-4 (-36 %, standard error 1.16e-4); 72 s alone."""

import json

import pytest

import jaxmodel as jm
from identification import cli
from identification.drive_log import write_drive
from identification.simulate import simulate

START = dict(P=0.125, B=2.70, T_F=1.55, a=0.0)
VEHICLE = dict(P=0.125, B=2.70, T_F=1.59, a=3.0e-4)
TRAIN = [("mixed", 240.0), ("urban", 180.0)]


@pytest.mark.slow
def test_identify_cli_from_a_zero_recovers_the_vehicle(tmp_path, capsys):
    start = tmp_path / "start.json"
    start.write_text(json.dumps(START))
    drives = []
    for i, (scenario, duration) in enumerate(TRAIN):
        path = tmp_path / f"train_{scenario}.csv"
        write_drive(path, simulate(scenario, duration, seed=i, params=VEHICLE)[0])
        drives.append(str(path))
    before = {p: open(p, "rb").read() for p in drives + [str(start)]}
    out = tmp_path / "fit.json"
    assert cli.main(["identify", *drives, "--params", str(start), "--out", str(out), "--fit", "T_F,a"]) == 0
    err = capsys.readouterr().err
    fitted = json.loads(out.read_text())
    report = fitted.pop("report")
    rows = report["parameters"]
    assert "a starts at 0" in err
    assert rows["a"]["transform"] == "softplus"
    assert fitted["a"] > 0.0
    assert abs(fitted["T_F"] / VEHICLE["T_F"] - 1.0) < 0.005, rows["T_F"]
    assert abs(fitted["a"] - VEHICLE["a"]) < 4 * rows["a"]["std_error"], rows["a"]
    assert abs(fitted["a"] / VEHICLE["a"] - 1.0) < 0.5, rows["a"]
    jm.validate_params(jm.make_params(fitted))  # usable by estimate and build-fmu
    assert {p: open(p, "rb").read() for p in before} == before
