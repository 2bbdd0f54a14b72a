"""The native OdoCompass FMU (issue 12): the FMI 2.0 C API around the step that fmu/jaxpr_lower.py
generates from jaxmodel's jaxpr, no Python at run time; both FMUs from one model description;
bad samples never end a run; errors are errors; the pythonfmu exit-time abort is gone.

The native FMU is built once per test process with the test parameters (CUSTOM of test_fmu.py) and a
subset of the configurations (every mode, and the table track); ``odocompass build-fmu --native``
compiles all of them.  It holds no Python, so it is stepped in this process.
"""

from __future__ import annotations

import atexit
import functools
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from test_fmu import CUSTOM, REPO, built_fmus, custom_params, run_py, wrap

pytestmark = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None,
                                reason="the native FMU needs a C compiler at build time")

TEST_CONFIGS = [dict(mode=m, refine_a=True, calibration=True, track="closed_form")
                for m in ("complementary", "odometer", "compass", "kalman")] + \
               [dict(mode="complementary", refine_a=False, calibration=False, track="table")]


@functools.lru_cache(maxsize=None)
def native_fmu() -> Path:
    from fmu.native_fmu import build_native_fmu

    d = Path(tempfile.mkdtemp(prefix="odocompass_test_native_"))
    atexit.register(shutil.rmtree, d, True)  # the session's FMU; nothing left behind in the temp folder
    return build_native_fmu(d / "OdoCompassNative.fmu", CUSTOM, configs=TEST_CONFIGS)


@pytest.fixture(scope="module")
def native():
    return native_fmu()


def _md(path):
    from fmpy import read_model_description

    return read_model_description(str(path))


# ----------------------------------------------------------------------------------------------
# the FMU: no Python, sources, one model description for both FMUs
# ----------------------------------------------------------------------------------------------
def test_native_fmu_is_valid_and_has_no_python(native):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(native)) == []
    md = _md(native)
    assert md.coSimulation.modelIdentifier == "OdoCompassNative" and not md.coSimulation.needsExecutionTool
    with zipfile.ZipFile(native) as z:
        names = set(z.namelist())
        xml = z.read("modelDescription.xml").decode()
        lib = z.read("binaries/linux64/OdoCompassNative.so")
    assert not any(n.startswith("resources/") for n in names)  # no bundled Python
    sources = [f"sources/{n}" for n in ("odocompass_fmi2.c", "odocompass_fmi2_state.c", "odocompass_fmi2.h",
                                        "odocompass_validate.c", "odocompass_model.h")]
    assert set(sources) <= names and len([n for n in names if n.startswith("sources/odc_step_")]) == len(TEST_CONFIGS)
    for n in names:
        if n.startswith("sources/") and n.endswith(".c"):
            assert f'<File name="{n[8:]}"' in xml, n
    with tempfile.NamedTemporaryFile(suffix=".so") as f:
        f.write(lib)
        f.flush()
        needed = subprocess.run(["readelf", "-d", f.name], capture_output=True, text=True).stdout
        exported = subprocess.run(["nm", "-D", "--defined-only", f.name], capture_output=True, text=True).stdout
    libs = {line.split("[")[1].split("]")[0] for line in needed.splitlines() if "NEEDED" in line}
    assert libs <= {"libm.so.6", "libc.so.6"}, libs
    symbols = {line.split()[-1] for line in exported.splitlines() if " T " in line}
    assert "fmi2DoStep" in symbols and all(s.startswith("fmi2") for s in symbols), symbols


def test_both_fmus_share_variables_units_and_default_experiment(native):
    py = _md(built_fmus()["estimator"])
    nat = _md(native)

    def table(md):
        return [(v.name, v.valueReference, v.type, v.causality, v.variability, v.unit, v.min, v.max, v.start)
                for v in md.modelVariables]

    assert table(py) == table(nat)
    assert [(u.name, str(u.baseUnit)) for u in py.unitDefinitions] == [(u.name, str(u.baseUnit))
                                                                       for u in nat.unitDefinitions]
    for attr in ("startTime", "stopTime", "stepSize"):
        assert getattr(py.defaultExperiment, attr) == getattr(nat.defaultExperiment, attr)
    assert float(nat.defaultExperiment.stopTime) > 0


def test_model_description_as_an_fmi_expert_expects(native):
    from jaxmodel.params import PARAMETER_TABLE

    md = _md(native)
    by = {v.name: v for v in md.modelVariables}
    # outputs change only in fmi2DoStep: no direct feedthrough
    assert md.outputs and all(u.dependencies == [] for u in md.outputs)
    for flag in ("compass_valid", "odometer_valid", "map_used", "initialized"):
        assert by[flag].type == "Boolean" and by[flag].causality == "output"
    assert by["counter_modulus"].type == "Integer" and int(by["counter_modulus"].min) == 1
    assert float(by["P"].min) == 0.0 and float(by["P"].max) == math.nextafter(1.0, 0.0)
    assert float(by["B"].min) > 0.0 and float(by["curvature_clip"].max) < 1.0
    # every unit has base units (the compass unit declared as uT)
    with zipfile.ZipFile(native) as z:
        xml = z.read("modelDescription.xml").decode()
    assert xml.count("<Unit ") == xml.count("<BaseUnit")
    assert {spec.key for spec in PARAMETER_TABLE} <= {v.name for v in md.modelVariables} | {
        f"{k}" for k in ("deviation_deg",)}


# ----------------------------------------------------------------------------------------------
# equivalence: odocompass estimate within 1e-12 rad at every sample
# ----------------------------------------------------------------------------------------------
def test_native_fmu_equals_odocompass_estimate(native, tmp_path):
    import jaxmodel
    from fmu.cosim import replay
    from identification.estimate import estimate_drive
    from test_fmu import _simulated_drive

    params = custom_params()
    for name, kw, start in (("clean", {}, None),
                            ("faulty", dict(scenario="urban", duration=120.0, seed=6, faults=True),
                             {"discard_bad_samples": False}),
                            ("kalman", dict(scenario="urban", duration=60.0, seed=4), {"mode": "kalman"})):
        drive, _ = _simulated_drive(tmp_path, name, **kw)
        cols = {f: np.asarray(getattr(drive.inputs, f)) for f in drive.inputs._fields}
        out = replay(native, cols, start)
        mode = (start or {}).get("mode", "complementary")
        cfg = jaxmodel.Config(mode=mode)
        est = np.deg2rad(np.asarray(estimate_drive(params, drive)["heading_deg"], dtype=np.float64)) \
            if mode == "complementary" else np.asarray(jaxmodel.run(params, drive.inputs, cfg).heading)
        worst = float(np.max(np.abs(wrap(out["heading"] - est))))
        assert worst <= 1e-12, f"{name}: {worst:.3g} rad"
        ref = jaxmodel.run(params, drive.inputs, cfg)
        for field in jaxmodel.Outputs._fields:
            got = out["a_current" if field == "a" else field]
            want = np.asarray(getattr(ref, field), dtype=np.float64)
            if field in ("heading", "wheel_heading", "compass_heading", "f_delta"):
                err = np.abs(wrap(got - want))
                assert np.nanmax(err) <= 1e-12 and np.array_equal(np.isnan(got), np.isnan(want)), (name, field)
            else:  # the C library's elementary functions differ from XLA's in the last bits
                assert np.allclose(got, want, rtol=1e-9, atol=1e-9, equal_nan=True), (name, field)


# ----------------------------------------------------------------------------------------------
# behaviour: state, reset, instances, bad samples, bad parameters, access errors (fmu.selfcheck)
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def selfcheck(native):
    from fmu.selfcheck import check_all, failures

    res = check_all(str(native))
    return res, failures(res)


def test_native_selfcheck_passes(selfcheck):
    res, bad = selfcheck
    assert bad == []
    for case, r in res["bad_inputs"].items():
        if "status" in r:
            assert r["status"] == "WARNING", case  # skipped: fmi2Warning, the run goes on


def test_a_wheel_counter_that_stopped_is_logged_once_with_its_end(selfcheck):
    r = selfcheck[0]["stopped_counter"]
    assert r["warned_once"] and r["end_reported"] and r["clean_quiet"], r["messages"]
    since = re.search(r"since t=([-+.e0-9]+) s", r["messages"][0][2])
    assert since and float(since.group(1)) == pytest.approx(11.9), r["messages"]


@pytest.mark.parametrize("key", ["P", "T_F", "B", "sensor_axle", "mode"])
def test_invalid_parameters_fail_initialization_with_fmi2error(selfcheck, key):
    r = selfcheck[0]["bad_parameters"][key]
    assert r["init_error"] == 3 and r["named"], r


def test_access_errors_are_fmi2error(selfcheck):
    r = selfcheck[0]["access"]
    assert r["fixed_parameter"]["status"] == "ERROR" and r["unknown_variable"]["status"] == "ERROR"
    assert r["B_unchanged"]


def test_order_rule_and_unknown_configuration_are_refused(native):
    from fmpy.fmi1 import FMICallException
    from fmu.cosim import Slave

    for params, words in (({"refine_speed_min": 30.0}, ["refine_speed_min", "refine_speed_max"]),
                          ({"track": "table"}, ["configuration", "track=table"]),
                          ({"counter_modulus": 0}, ["counter_modulus"])):
        s = Slave(native, "bad")
        with pytest.raises(FMICallException):
            s.initialize(0.0, params, {"compass_x": 20.0, "compass_y": 0.0})
        text = " ".join(m[2] for m in s.messages if m[0] == "ERROR")
        s.close()
        assert all(w in text for w in words), text
    s = Slave(native, "table")  # a compiled table-track configuration works
    s.initialize(0.0, {"track": "table", "refine_a": False, "calibration": False}, {"compass_x": 20.0})
    s.close()


def test_memory_flat_over_1000_instantiate_free_cycles(native):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(native))
    d = extract(str(native))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier="OdoCompassNative", instanceName="m")

    def rss():
        return int(Path("/proc/self/statm").read_text().split()[1]) * 4096

    def cycle():
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.doStep(0.0, 0.1)
        fmu.terminate()
        fmu.fmi2FreeInstance(fmu.component)

    for _ in range(100):
        cycle()
    before = rss()
    for _ in range(1000):
        cycle()
    grown = rss() - before
    fmu.freeLibrary()
    shutil.rmtree(d, ignore_errors=True)
    assert grown < 256 * 1024, f"RSS grew by {grown} bytes over 1000 cycles"


# ----------------------------------------------------------------------------------------------
# one bad row never ends a co-simulation: fmpy.simulate_fmu runs to the stop time, both FMUs
# ----------------------------------------------------------------------------------------------
SIMULATE_NAN_ROW = """
import json, sys
import numpy as np
from fmpy import simulate_fmu
t = np.arange(601) * 0.1
rows = np.zeros(601, dtype=[("time", float), ("left_pulses", np.int32), ("right_pulses", np.int32),
                            ("compass_x", float), ("compass_y", float)])
rows["time"] = t
rows["left_pulses"] = np.floor(t * 500.0).astype(np.int32)
rows["right_pulses"] = np.floor(t * 495.0).astype(np.int32)
rows["compass_x"], rows["compass_y"] = 20.0, 1.0
rows["compass_x"][200] = np.nan
res = simulate_fmu(sys.argv[1], input=rows, output_interval=0.1, stop_time=60.0,
                   output=["heading", "discarded_samples"], logger=lambda *a: None)
print(json.dumps({"rows": len(res), "end": float(res["time"][-1]), "discarded": int(res["discarded_samples"][-1]),
                  "finite": bool(np.all(np.isfinite(res["heading"])))}))
"""


def test_one_nan_row_runs_to_the_stop_time_in_fmpy(native):
    for fmu in (native, built_fmus()["estimator"]):
        out = run_py(SIMULATE_NAN_ROW, fmu)
        assert out["rows"] == 601 and out["end"] == pytest.approx(60.0), (fmu, out)
        assert 1 <= out["discarded"] <= 2 and out["finite"], (fmu, out)


# ----------------------------------------------------------------------------------------------
# outputs read before initialization: the same in both FMUs
# ----------------------------------------------------------------------------------------------
OUTPUTS_BEFORE_INIT = """
import json, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
vr = {v.name: v.valueReference for v in md.modelVariables}
outs = [v.name for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
s = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]), modelIdentifier=md.coSimulation.modelIdentifier,
              instanceName="early")
s.instantiate(loggingOn=False)
read = {"instantiated": s.getReal([vr[o] for o in outs])}
s.setReal([vr["compass_x"]], [-20.0])  # a value set before initialization changes what is read next
read["instantiated, set"] = s.getReal([vr[o] for o in outs])
s.setupExperiment(startTime=0.0)
s.enterInitializationMode()
read["initialization"] = s.getReal([vr[o] for o in outs])
s.exitInitializationMode()
read["stepping"] = s.getReal([vr[o] for o in outs])
s.terminate()
s.freeInstance()
print(json.dumps({"outputs": outs, "read": read}))
"""


def test_outputs_read_before_initialization_agree_between_the_fmus(native):
    """Before stop 45 the pythonfmu FMU answered NaN in the instantiated state, the native FMU the outputs of the
    start values; both now compute them from the values set so far, as initialization mode does."""
    got = [run_py(OUTPUTS_BEFORE_INIT, fmu) for fmu in (native, built_fmus()["estimator"])]
    for out in got:
        read = out["read"]
        assert all(math.isfinite(v) for v in read["instantiated"]), out
        assert read["instantiated, set"] == read["initialization"] == read["stepping"], out
        assert read["instantiated"] != read["instantiated, set"], out
    for phase, values in got[0]["read"].items():
        np.testing.assert_allclose(got[1]["read"][phase], values, rtol=1e-9, atol=1e-12, err_msg=phase)


# ----------------------------------------------------------------------------------------------
# a damaged serialized state is refused, never run
# ----------------------------------------------------------------------------------------------
DAMAGED_STATE = """
import json, struct, sys
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
vr = {v.name: v.valueReference for v in md.modelVariables}
s = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]), modelIdentifier=md.coSimulation.modelIdentifier,
              instanceName="damaged")
s.instantiate(loggingOn=False)
s.setupExperiment(startTime=0.0)
s.enterInitializationMode()
s.exitInitializationMode()
s.setReal([vr["compass_x"], vr["compass_y"]], [20.0, 1.0])
s.doStep(0.0, 0.1)
state = s.getFMUstate()
good = bytes(s.serializeFMUstate(state))
s.freeFMUstate(state)
refused = {}
# odc_saved: magic, size, guid[64], then odc_dyn: phase, config (int32 each)
for name, offset, value in (("config -7", 76, -7), ("config 1e6", 76, 10 ** 6), ("phase 9", 72, 9)):
    bad = bytearray(good)
    struct.pack_into("<i", bad, offset, value)
    try:
        s.setFMUstate(s.deSerializeFMUstate(bytes(bad)))
        s.doStep(0.1, 0.1)
        refused[name] = False
    except FMICallException:
        refused[name] = True
s.setFMUstate(s.deSerializeFMUstate(good))  # the instance is still usable
s.doStep(0.1, 0.1)
s.terminate()
s.freeInstance()
print(json.dumps(refused))
"""


def test_a_damaged_serialized_state_is_refused_not_run(native):
    """Before stop 44 a state whose configuration index was negative passed fmi2SetFMUstate, and the next fmi2DoStep
    crashed the host (SIGSEGV)."""
    out = run_py(DAMAGED_STATE, native)
    assert out == {"config -7": True, "config 1e6": True, "phase 9": True}, out


PYTHONFMU_DAMAGED_STATE = """
import json, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
md = read_model_description(sys.argv[1])
vr = {v.name: v.valueReference for v in md.modelVariables}
where = extract(sys.argv[1])
messages = []
callbacks = fmi2CallbackFunctions()
callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, category, msg: messages.append(msg.decode()))
def instance(name):
    s = FMU2Slave(guid=md.guid, unzipDirectory=where, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    s.instantiate(callbacks=callbacks, loggingOn=True)
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    return s
def step(s, k):
    s.setInteger([vr["left_pulses"], vr["right_pulses"]], [50 * k, 49 * k])
    s.setReal([vr["compass_x"], vr["compass_y"]], [20.0, 1.0])
    s.doStep(0.1 * (k - 1), 0.1)
    return s.getReal([vr["heading"], vr["distance"]])
s, twin = instance("s"), instance("twin")
step(s, 1), step(twin, 1)
state = s.getFMUstate()
good = json.loads(bytes(s.serializeFMUstate(state)))
s.freeFMUstate(state)
damage = {"short s": lambda j: j.update(s=j["s"][:5]), "short x": lambda j: j.update(x=j["x"][:2]),
          "no B": lambda j: j["params"].pop("B"), "format": lambda j: j.update(format="other/1")}
refused = {}
for name, spoil in damage.items():
    bad = json.loads(json.dumps(good))
    spoil(bad)
    del messages[:]
    s.setFMUstate(s.deSerializeFMUstate(json.dumps(bad).encode()))
    refused[name] = any("refused, the instance is unchanged" in m for m in messages)
same = all(step(s, k) == step(twin, k) for k in range(2, 6))  # unchanged: it steps as its twin
del messages[:]
s.setInteger([vr["compass_x"]], [5])  # a Real through the Integer call: refused, the value kept
kept = s.getReal([vr["compass_x"]]) == [20.0]
s.getReal([vr["left_pulses"]])  # an Integer through the Real call
wrong_type = sum("refused" in m for m in messages)
print(json.dumps({"refused": refused, "same": same, "kept": kept, "wrong_type": wrong_type}))
"""


def test_the_pythonfmu_fmu_refuses_a_damaged_state_and_the_wrong_type():
    """Before stop 44 a state with a short input vector passed, and the next fmi2SetInteger was fmi2Fatal; a missing
    parameter silently took its default; fmi2SetInteger set a Real input and fmi2GetReal read an Integer, silently.
    (pythonfmu 0.7.0 answers such calls OK: the error-status message is what it allows; the native FMU: fmi2Error.)"""
    out = run_py(PYTHONFMU_DAMAGED_STATE, built_fmus()["estimator"])
    assert out == {"refused": {"short s": True, "short x": True, "no B": True, "format": True}, "same": True,
                   "kept": True, "wrong_type": 2}, out


# ----------------------------------------------------------------------------------------------
# a master stepping faster than the sensor: fmpy holds the counters between input rows
# ----------------------------------------------------------------------------------------------
SIMULATE_FAST_MASTER = """
import json, sys
import numpy as np
from fmpy import simulate_fmu
from fmpy.util import read_csv
rows = read_csv(sys.argv[2])
outs = ["heading", "speed", "distance", "discarded_samples"]
quiet = dict(output=outs, logger=lambda *a: None)
ref = simulate_fmu(sys.argv[1], input=rows, output_interval=0.1, **quiet)
fast = simulate_fmu(sys.argv[1], input=rows, output_interval=0.02, **quiet)
early = rows.copy()
early["time"] = early["time"] - 1e-6  # fmpy then steps 1 us to each input row
shifted = simulate_fmu(sys.argv[1], input=early, output_interval=0.1, **quiet)
at = np.searchsorted(fast["time"], ref["time"] - 1e-9)
dh = np.degrees(np.abs(np.angle(np.exp(1j * (fast["heading"][at] - ref["heading"])))))
print(json.dumps({"max_dheading_deg": float(dh.max()), "distance": [float(r["distance"][-1]) for r in (ref, fast, shifted)],
                  "discarded": [int(r["discarded_samples"][-1]) for r in (ref, fast, shifted)],
                  "max_speed": [float(r["speed"].max()) for r in (ref, fast, shifted)]}))
"""


def test_a_master_stepping_faster_than_the_sensor_keeps_the_drive(native):
    """Before stop 44, stepping at 0.02 s on the 10-Hz example put the heading 8.1 deg off the 0.1-s run with no
    message (each held counter update taken for a burst at 5 x the speed), and input rows 1 us off the output grid
    discarded 442 of 601 samples and read 40,000 m/s.  Now the update covers the time since the counts changed."""
    example = REPO / "fmu" / "examples" / "OdoCompass_in.csv"
    for fmu in (native, built_fmus()["estimator"]):
        out = run_py(SIMULATE_FAST_MASTER, fmu, example)
        assert out["discarded"] == [0, 0, 0], (fmu, out)
        ref_distance, fast_distance, shifted_distance = out["distance"]
        assert fast_distance == pytest.approx(ref_distance, rel=1e-9), (fmu, out)
        # rows 1 us early apply from their own time, one step before the unshifted ones (fmpy's discrete inputs at an
        # event take the row before; docs/fmu.md): the shifted run has seen one more sample at 60 s
        assert 0.0 <= shifted_distance - ref_distance <= 0.1 * out["max_speed"][0] + 1e-6, (fmu, out)
        assert max(out["max_speed"]) <= out["max_speed"][0] + 1e-6, (fmu, out)
        # the compass, interpolated by fmpy between rows, is sampled 5 x as often: 0.62 deg measured
        assert out["max_dheading_deg"] <= 1.0, (fmu, out)


# ----------------------------------------------------------------------------------------------
# the pythonfmu FMU's exit-time abort (soak: bench/bench_fmu.py, 500 processes)
# ----------------------------------------------------------------------------------------------
EXIT_SCRIPT = """
import sys
from fmu.cosim import Slave
for i in range(4):
    s = Slave(sys.argv[1], f"i{i}")
    s.initialize(0.0, None, {"compass_x": 20.0, "compass_y": 1.0, "left_pulses": 0, "right_pulses": 0})
    s.set({"left_pulses": 10, "right_pulses": 10})
    s.step(0.0, 0.1)
    s.close()
print("{}")
"""


def test_pythonfmu_fmu_processes_exit_normally():
    """10 processes that each run four instances and exit normally (no os._exit): all exit 0."""
    fmu = built_fmus()["estimator"]
    codes = []
    for _ in range(10):
        proc = subprocess.run([sys.executable, "-c", EXIT_SCRIPT, str(fmu)],
                              capture_output=True, text=True, cwd=tempfile.gettempdir(),
                              env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=300)
        codes.append(proc.returncode)
    assert codes == [0] * 10, codes


# ----------------------------------------------------------------------------------------------
# a C++ host: libcosim (the Open Simulation Platform's master, pip package libcosimpy)
# ----------------------------------------------------------------------------------------------
LIBCOSIM = """
import json, sys
import numpy as np
from fmpy import read_model_description
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimManipulator import CosimManipulator
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

log_output_level(CosimLogLevel.ERROR)
fmu, drive, out = sys.argv[1], sys.argv[2], sys.argv[3]
data = np.load(drive)
vr = {v.name: v.valueReference for v in read_model_description(fmu).modelVariables}
ex = CosimExecution.from_step_size(step_size=100_000_000)  # 0.1 s in ns, one sample per step
idx = ex.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name="odocompass"))
obs = CosimObserver.create_last_value()
ex.add_observer(obs)
man = CosimManipulator.create_override()
ex.add_manipulator(man)
ints, reals = ("left_pulses", "right_pulses"), ("compass_x", "compass_y")
for n in ints:
    ex.integer_initial_value(idx, vr[n], int(data[n][0]))
for n in reals:
    ex.real_initial_value(idx, vr[n], float(data[n][0]))
heading = []
for k in range(1, len(data["time_s"])):
    man.slave_integer_values(idx, [vr[n] for n in ints], [int(data[n][k]) for n in ints])
    man.slave_real_values(idx, [vr[n] for n in reals], [float(data[n][k]) for n in reals])
    assert ex.step(), f"libcosim step {k} failed"
    heading.append(obs.last_real_values(idx, [vr["heading"]])[0])
np.save(out, np.asarray(heading))
print(json.dumps({"steps": len(heading), "end_time": ex.status().current_time * 1e-9}))
"""


def test_libcosim_runs_both_fmus_and_matches_odocompass_estimate(native, tmp_path):
    pytest.importorskip("libcosimpy", reason="libcosimpy (pip) is not installed")
    import jaxmodel
    from identification.drive_log import drive_from_columns
    from identification.estimate import estimate_drive
    from identification.simulate import simulate

    cols, _ = simulate("urban", 40.0, 3, params=jaxmodel.params_to_dict(custom_params()))
    n = len(cols["time_s"])
    cols = dict(cols, time_s=0.1 * np.arange(n))  # the master's fixed 0.1 s grid: sample k at k * 0.1 s
    drive = drive_from_columns(cols, source="libcosim")
    path = tmp_path / "drive.npz"
    np.savez(path, **{f: np.asarray(getattr(drive.inputs, f)) for f in drive.inputs._fields})
    est = np.deg2rad(np.asarray(estimate_drive(custom_params(), drive)["heading_deg"], dtype=np.float64))
    for name, fmu in (("native", native), ("pythonfmu", built_fmus()["estimator"])):
        out = run_py(LIBCOSIM, fmu, path, tmp_path / f"{name}.npy")
        assert out["steps"] == n - 1 and out["end_time"] == pytest.approx(0.1 * (n - 1)), (name, out)
        got = np.load(tmp_path / f"{name}.npy")
        worst = float(np.max(np.abs(wrap(got - est[1:]))))
        assert worst <= 1e-9, f"{name} in libcosim: heading differs from odocompass estimate by {worst:.3g} rad"


# ----------------------------------------------------------------------------------------------
# the examples are a reference: no aliased rows; the checker's own input sampling gives the reference
# ----------------------------------------------------------------------------------------------
def test_example_reference_matches_a_fresh_fmu_under_the_checkers_sampling(tmp_path):
    from fmpy.util import read_csv

    from fmu.make_examples import OUTPUTS, ROW_LEAD_S, checker_replay
    from fmu.native_fmu import build_native_fmu

    examples = REPO / "fmu" / "examples"
    inp = read_csv(str(examples / "OdoCompass_in.csv"))
    ref = read_csv(str(examples / "OdoCompass_ref.csv"))
    t = np.asarray(inp["time"])
    assert t[0] == 0.0 and np.allclose(t[1:], 0.1 * np.arange(1, len(t)) - ROW_LEAD_S, rtol=0, atol=1e-12)
    fmu = build_native_fmu(tmp_path / "OdoCompassNative.fmu", configs=[])  # default parameters
    got = checker_replay(fmu, examples / "OdoCompass_in.csv", float(ref["time"][-1]))
    assert len(got["time"]) == len(ref)
    assert np.allclose(got["time"], ref["time"], rtol=0, atol=1e-9)
    for name in OUTPUTS:
        a, b = np.asarray(got[name]), np.asarray(ref[name])
        err = np.abs(wrap(a - b)) if name in ("heading", "wheel_heading", "compass_heading") else \
            np.abs(a - b) / np.maximum(1.0, np.abs(b))
        assert float(np.max(err)) <= 1e-9, f"OdoCompass_ref.csv is stale or aliased: {name} differs by {np.max(err):.3g}"
    # counters sampled as a real sensor: no repeated count while the reference says the car moves
    left = np.asarray(inp["left_pulses"], dtype=float)
    fast = np.asarray(ref["speed"])[2:] > 1.0  # speed at t_{k+1} comes from row k
    assert not np.any((np.diff(left)[:len(fast)] == 0) & fast)


def test_build_fmu_native_command_line(native, monkeypatch, capsys, tmp_path):
    """``odocompass build-fmu --native``: the native builder, default --out build/OdoCompassNative.fmu
    (the full 32-configuration build takes minutes; the builder itself is exercised by the fixture)."""
    import fmu.native_fmu
    from identification.cli import main

    calls = []

    def fake(out, params):
        calls.append((Path(out).name, params))
        shutil.copy2(native, out)
        return out

    monkeypatch.setattr(fmu.native_fmu, "build_native_fmu", fake)
    monkeypatch.chdir(tmp_path)
    assert main(["build-fmu", "--native"]) == 0
    assert (tmp_path / "build" / "OdoCompassNative.fmu").is_file()
    params = tmp_path / "p.json"
    params.write_text(json.dumps(CUSTOM))
    assert main(["build-fmu", "--native", "--params", str(params), "--out", str(tmp_path / "N.fmu")]) == 0
    assert [c[1] for c in calls] == [None, str(params)] and (tmp_path / "N.fmu").is_file()
    assert "22 outputs" in capsys.readouterr().err  # an information line (stderr, silenced by -q)
