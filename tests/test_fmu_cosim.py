"""The FMU in co-simulation (issue 5): VehicleSensors -> OdoCompass with the master of fmu/cosim.py and
as an SSP run by fmpy.ssp.simulate_ssp; fmpy.simulate_fmu on the example input (Reference-FMUs
convention); the vehicle FMU's state.  All FMU runs happen in subprocesses (see test_fmu.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from test_fmu import REPO, built_fmus, custom_params, run_py, wrap

EXAMPLES = REPO / "fmu" / "examples"


@pytest.fixture(scope="module")
def fmus():
    return built_fmus()


COSIM = """
import json, sys
import numpy as np
from fmu.cosim import demo_cosimulation
s = demo_cosimulation(sys.argv[1], sys.argv[2], sys.argv[3], stop_time=float(sys.argv[4]))
np.savez(sys.argv[1] + "/series.npz", time=s["time"], true=s["true_heading"], est=s["heading"])
print(json.dumps({k: v for k, v in s.items() if k not in ("time", "true_heading", "heading", "series")}))
"""


def test_cosimulation_and_ssp_run_to_stop_time_and_track_the_truth(fmus, tmp_path):
    out = run_py(COSIM, tmp_path, fmus["estimator"], fmus["vehicle"], 600.0)
    assert out["end_time"] == pytest.approx(600.0, abs=1e-9)
    assert out["ssp_end_time"] == pytest.approx(600.0, abs=1e-6)
    assert out["discarded"] == 0
    # same parameters in both FMUs: the estimate follows the vehicle's true heading
    assert out["rmse_deg"] < 3.0, out
    assert out["ssp_rmse_deg"] < 3.0, out
    assert Path(out["plot"]).stat().st_size > 10_000
    s = np.load(tmp_path / "series.npz")
    assert s["time"][-1] == pytest.approx(600.0)
    assert float(np.max(np.abs(np.degrees(wrap(s["est"] - s["true"]))))) < 10.0
    # the .ssp is a valid SSP 1.0 package (fmpy validates the SSD against the schema)
    from fmpy.ssp.ssd import read_ssd

    ssd = read_ssd(out["ssp_path"], validate=True)
    assert {e.name for e in ssd.system.elements} == {"vehicle", "estimator"}
    assert len(ssd.system.connections) == 9


SIMULATE_FMU = """
import json, sys
import numpy as np
from fmpy import simulate_fmu
from fmpy.util import read_csv
inp = read_csv(sys.argv[2])
res = simulate_fmu(sys.argv[1], input=inp, output=["heading", "x", "y"], output_interval=0.1,
                   stop_time=float(inp["time"][-1]))
np.savez(sys.argv[3], time=res["time"], heading=res["heading"], x=res["x"], y=res["y"])
print(json.dumps({"end": float(res["time"][-1])}))
"""


def test_fmpy_simulate_fmu_on_the_example_input(fmus, tmp_path):
    """fmpy.simulate_fmu sets row t before doStep(t, 0.1); the FMU stamps it t + 0.1 (docs/fmu.md)."""
    import jaxmodel
    from fmpy.util import read_csv

    in_csv = EXAMPLES / "OdoCompass_in.csv"
    ref_csv = EXAMPLES / "OdoCompass_ref.csv"
    inp = read_csv(str(in_csv))
    ref_file = read_csv(str(ref_csv))
    assert list(inp.dtype.names) == ["time", "left_pulses", "right_pulses", "compass_x", "compass_y"]
    assert ref_file.dtype.names[0] == "time" and "heading" in ref_file.dtype.names
    assert len(ref_file) == len(inp)
    out = run_py(SIMULATE_FMU, fmus["estimator"], in_csv, tmp_path / "sim.npz")
    t = inp["time"]
    assert out["end"] == pytest.approx(float(t[-1]), abs=1e-9)
    res = np.load(tmp_path / "sim.npz")
    assert len(res["time"]) == len(t)  # no extra steps: the rows never fall between communication points
    # expected: the initialization sample (row 0 at t0), then row k-1's values stamped t_k (the rows
    # are stamped 1e-11 s before their communication point, fmu/make_examples.py)
    idx = np.concatenate([[0], np.arange(len(t) - 1)])
    samples = jaxmodel.make_inputs(res["time"], inp["left_pulses"][idx].astype(float),
                                   inp["right_pulses"][idx].astype(float),
                                   inp["compass_x"][idx], inp["compass_y"][idx])
    want = jaxmodel.run(custom_params(), samples)
    assert len(res["time"]) == len(t)
    assert float(np.max(np.abs(wrap(res["heading"] - np.asarray(want.heading))))) <= 1e-9
    assert float(np.max(np.abs(res["x"] - np.asarray(want.x)))) <= 1e-6


VEHICLE_STATE = """
import json, sys
from fmu.cosim import Slave, demo_profile
s = Slave(sys.argv[1], "vehicle")
s.initialize(0.0, {"seed": 4, "anomaly_density_per_km2": 5.0, "transient_rate_per_s": 0.05})
names = ["left_pulses", "right_pulses", "compass_x", "compass_y", "true_heading", "x", "y"]
def run(k0, k1):
    out = []
    for k in range(k0, k1):
        st, sp = demo_profile(0.1 * k)
        s.set({"steering_angle": st, "speed": sp})
        assert s.step(0.1 * k, 0.1)
        out.append(s.get(names))
    return out
run(0, 400)
state = s.fmu.getFMUstate()
blob = s.fmu.serializeFMUstate(state)
a = run(400, 500)
s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(blob))
b = run(400, 500)
s.close()
print(json.dumps({"same": a == b, "moved": a[-1]["x"] != a[0]["x"]}))
"""


def test_vehicle_fmu_state_restores_exactly(fmus):
    out = run_py(VEHICLE_STATE, fmus["vehicle"])
    assert out["same"] and out["moved"]
