"""The OdoCompass FMU (issue 5, SPEC §7): model description, build-fmu, equivalence with
``odocompass estimate``, state save/restore, independence, bad input, host isolation.

FMUs are built once per test run (``built_fmus``, shared with test_fmu_cosim.py, test_fmu_native.py
and the other xdist worker).  Everything
that steps an FMU runs in a subprocess that never imports ``jaxmodel``, so a bundling fault cannot
be masked by the test process's own imports; references are computed here with ``jaxmodel``.
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
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_RUN_DIR_ENV

REPO = Path(__file__).resolve().parents[1]

CUSTOM = {  # start values of the test build: not the defaults, so the FMU must use its own
    "P": 0.14, "B": 2.85, "T_F": 1.58, "T_R": 1.57, "a": 1.5e-4, "D_N": 350.0, "variation_deg": 2.5,
    "X0": 0.4, "Y0": -0.3, "rotation_deg": 1.0,
    "deviation_deg": [round(0.8 * math.sin(2.0 * math.pi * i / 36.0) + 0.3 * math.cos(4.0 * math.pi * i / 36.0), 6)
                      for i in range(36)],
}
SPEC_OUTPUTS = {"heading": "rad", "wheel_heading": "rad", "compass_heading": "rad", "x": "m", "y": "m",
                "speed": "m/s", "a_current": "s2/m2", "heading_reliability": "1"}


@functools.lru_cache(maxsize=None)
def built_fmus() -> dict[str, Path]:
    """Build once per test run: the estimator through the CLI (SPEC §5) with CUSTOM start values, and the vehicle.

    The FMUs go to the run's shared folder (conftest: ODOCOMPASS_TEST_RUN_DIR): the first xdist worker to ask
    builds them under a file lock, the other finds them there (a build is ~1 minute, ~2 with both workers busy).
    Without that folder (this module imported outside the suite) each process builds its own."""
    import fcntl

    shared = os.environ.get(SHARED_RUN_DIR_ENV, "")
    if not os.path.isdir(shared):
        d = Path(tempfile.mkdtemp(prefix="odocompass_test_fmu_"))
        atexit.register(shutil.rmtree, d, True)
        return _build_fmus(d)
    d = Path(shared) / "fmus"
    d.mkdir(exist_ok=True)
    with open(d / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also if the build fails
        done = d / "built.json"
        if done.is_file() and json.loads(done.read_text()) == CUSTOM:
            return _fmu_paths(d)
        out = _build_fmus(d)
        done.write_text(json.dumps(CUSTOM))
        return out


def _fmu_paths(d: Path) -> dict[str, Path]:
    """Where ``_build_fmus(d)`` puts the FMUs and their parameter file."""
    return {"estimator": d / "OdoCompass.fmu", "vehicle": d / "VehicleSensors.fmu", "params": d / "params.json",
            "dir": d}


def _build_fmus(d: Path) -> dict[str, Path]:
    import jax

    jax.config.update("jax_enable_x64", True)
    from fmu.build import build_vehicle
    from identification.cli import main

    out = _fmu_paths(d)
    out["params"].write_text(json.dumps(CUSTOM))
    assert main(["build-fmu", "--params", str(out["params"]), "--out", str(out["estimator"])]) == 0
    assert build_vehicle(out["vehicle"], out["params"]) == out["vehicle"]
    return out


@pytest.fixture(scope="module")
def fmus():
    return built_fmus()


def custom_params():
    import jaxmodel

    return jaxmodel.make_params(CUSTOM)


def run_py(code: str, *args: str, timeout: float = 900, env_extra: dict | None = None, cwd: Path | None = None):
    """Run ``code`` in a fresh interpreter (repo on PYTHONPATH, x64 not forced); returns its last stdout line as JSON."""
    env = dict(os.environ)
    env.pop("JAX_ENABLE_X64", None)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(env_extra or {})
    # The script exits normally: pythonfmu 0.7.0's exit-time abort is prevented by the slaves'
    # exit guard (fmu/fmi_support.py guard_pythonfmu_exit; docs/fmu.md).
    code = textwrap.dedent(code)
    proc = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=str(cwd or tempfile.gettempdir()))
    assert proc.returncode == 0, f"subprocess failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def wrap(a):
    a = np.asarray(a, dtype=np.float64)
    w = np.mod(a + math.pi, 2.0 * math.pi) - math.pi
    return np.where(w == -math.pi, math.pi, w)


# ----------------------------------------------------------------------------------------------
# model description and build
# ----------------------------------------------------------------------------------------------
def test_fmpy_validate_finds_no_problems(fmus):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmus["estimator"])) == []
    assert validate_fmu(str(fmus["vehicle"])) == []


def test_model_description(fmus):
    from fmpy import read_model_description

    from jaxmodel.params import PARAMETER_TABLE

    md = read_model_description(str(fmus["estimator"]))
    assert md.fmiVersion == "2.0"
    cs = md.coSimulation
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate and cs.canHandleVariableCommunicationStepSize
    assert float(md.defaultExperiment.stepSize) == 0.1
    units = {u.name for u in md.unitDefinitions}
    by_name = {v.name: v for v in md.modelVariables}
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real":
            assert v.unit in units, v.name
    # inputs (SPEC §7): counters are Integer (discrete), compass components Real
    assert (by_name["left_pulses"].type, by_name["left_pulses"].causality, by_name["left_pulses"].variability) == (
        "Integer", "input", "discrete")
    assert by_name["right_pulses"].type == "Integer"
    assert by_name["compass_x"].type == "Real" and by_name["compass_x"].causality == "input"
    for name in ("map_heading", "map_valid", "compass_unreliable_area", "fix_east_m", "fix_north_m", "fix_valid"):
        assert by_name[name].causality == "input"
    # outputs with units; every output is an initial unknown (valid after initialization)
    for name, unit in SPEC_OUTPUTS.items():
        assert by_name[name].causality == "output" and by_name[name].unit == unit, name
    outputs = {v.name for v in md.modelVariables if v.causality == "output"}
    assert {u.variable.name for u in md.initialUnknowns} == outputs == {u.variable.name for u in md.outputs}
    # parameters: the keys of PARAMETER_TABLE (deviation_deg as 36 entries), start values = the params file
    expected = set()
    for spec in PARAMETER_TABLE:
        if spec.key == "deviation_deg":
            expected |= {f"deviation_deg_{i}" for i in range(36)}
        else:
            expected.add(spec.key)
            if by_name[spec.key].type == "Real":
                assert by_name[spec.key].unit == (spec.unit or "1"), spec.key
    config = {"mode", "refine_a", "calibration", "track", "engine", "discard_bad_samples"}
    params = {v.name for v in md.modelVariables if v.causality == "parameter"}
    assert params == expected | config
    assert by_name["sensor_axle"].type == "String" and by_name["sensor_axle"].start == "front"
    for key, value in CUSTOM.items():
        if key == "deviation_deg":
            for i, x in enumerate(value):
                assert float(by_name[f"deviation_deg_{i}"].start) == x
        else:
            assert float(by_name[key].start) == value, key  # exact: written with repr
    rad = next(u for u in md.unitDefinitions if u.name == "rad")
    assert rad.baseUnit.rad == 1 and any(d.name == "deg" for d in rad.displayUnits)


def test_build_fmu_refuses_invalid_parameters(tmp_path, capsys):
    from identification.cli import main

    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"P": 1.5, "T_F": -1.0}))
    assert main(["build-fmu", "--params", str(bad), "--out", str(tmp_path / "x.fmu")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.json" in err[0] and "P=1.5" in err[0] and "T_F" in err[0]
    unknown = tmp_path / "unknown.json"
    unknown.write_text(json.dumps({"wheelbase": 2.7}))
    assert main(["build-fmu", "--params", str(unknown), "--out", str(tmp_path / "x.fmu")]) == 2
    assert "wheelbase" in capsys.readouterr().err
    assert not (tmp_path / "x.fmu").exists()


def test_native_libraries_built_and_checked(fmus):
    import zipfile

    with zipfile.ZipFile(fmus["estimator"]) as zf:
        manifest = json.loads(zf.read("resources/odocompass_bundle/manifest.json"))
        names = set(zf.namelist())
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler: the FMU runs the Python lowering")
    modes = {e["config"]["mode"] for e in manifest["native"]}
    assert modes == {"complementary", "odometer", "compass", "kalman"}, manifest["native_notes"]
    for e in manifest["native"]:
        assert e["check_max_rel_error"] <= 1e-9
        assert f"resources/odocompass_bundle/{e['file']}" in names
        assert f"resources/odocompass_bundle/{e['file'][:-3]}.c" in names  # the generated source ships too


# ----------------------------------------------------------------------------------------------
# the FMU in fmpy equals `odocompass estimate` at every sample
# ----------------------------------------------------------------------------------------------
REPLAY = """
import json, sys
import numpy as np
from fmu.cosim import replay
jobs = json.loads(sys.argv[1])
report = []
for job in jobs:
    data = np.load(job["drive"])
    cols = {k: data[k] for k in data.files}
    if job.get("n"):
        cols = {k: v[: job["n"]] for k, v in cols.items()}
    res = replay(job["fmu"], cols, job.get("parameters"))
    np.savez(job["out"], **{k: v for k, v in res.items() if k != "messages"})
    report.append({"messages": [m for m in res["messages"] if m[0] != "OK" or m[1] == "logEngine"][:10]})
print(json.dumps({"jobs": report, "public_jaxmodel_imported": any(
    m == "jaxmodel" or m.startswith("jaxmodel.") for m in sys.modules)}))
"""


def _simulated_drive(tmp_path, name, **kw):
    from identification.drive_log import drive_from_columns
    from identification.simulate import simulate

    params = custom_params()
    from jaxmodel import params_to_dict

    cols, _ = simulate(kw.pop("scenario", "mixed"), kw.pop("duration", 240.0), kw.pop("seed", 5),
                       params=params_to_dict(params), **kw)
    drive = drive_from_columns(cols, source=name)
    path = tmp_path / f"{name}.npz"
    np.savez(path, **{f: np.asarray(getattr(drive.inputs, f), dtype=np.float64) for f in drive.inputs._fields})
    return drive, path


def _compare(fmu_out, ref_cols, ref_out, n, label):
    """FMU outputs vs `odocompass estimate` (heading_deg) and vs jaxmodel.run (every output), at every sample."""
    import jaxmodel

    from fmu.build import OUTPUT_RENAMES

    h = fmu_out["heading"][:n]
    est = np.deg2rad(np.asarray(ref_cols["heading_deg"][:n], dtype=np.float64))
    worst_heading = float(np.max(np.abs(wrap(h - est))))
    assert worst_heading <= 1e-9, f"{label}: heading differs from odocompass estimate by {worst_heading:.3g} rad"
    for field in jaxmodel.Outputs._fields:
        got = fmu_out[OUTPUT_RENAMES.get(field, field)][:n]
        want = np.asarray(getattr(ref_out, field), dtype=np.float64)[:n]
        scale = np.maximum(1.0, np.abs(want))
        err = np.abs(got - want) / scale
        if field in ("heading", "wheel_heading", "compass_heading", "f_delta"):
            err = np.abs(wrap(got - want))
        assert float(np.max(err)) <= 1e-9, f"{label}: output {field} differs by {float(np.max(err)):.3g}"


def test_replayed_drive_equals_odocompass_estimate(fmus, tmp_path):
    import jaxmodel
    from identification.estimate import estimate_drive

    params = custom_params()
    clean, clean_path = _simulated_drive(tmp_path, "clean")
    faulty, faulty_path = _simulated_drive(tmp_path, "faulty", scenario="urban", duration=180.0, seed=6, faults=True)
    assert not np.all(np.isfinite(faulty.inputs.compass_x)), "the faulty drive must contain NaN compass samples"
    est = str(fmus["estimator"])
    jobs = [
        {"drive": str(clean_path), "fmu": est, "out": str(tmp_path / "auto.npz")},
        {"drive": str(clean_path), "fmu": est, "out": str(tmp_path / "python.npz"), "parameters": {"engine": "python"}},
        {"drive": str(clean_path), "fmu": est, "out": str(tmp_path / "xla.npz"), "parameters": {"engine": "xla"},
         "n": 400},
        {"drive": str(faulty_path), "fmu": est, "out": str(tmp_path / "faulty.npz"),
         "parameters": {"discard_bad_samples": False}},
    ]
    report = run_py(REPLAY, json.dumps(jobs))
    assert not report["public_jaxmodel_imported"]
    engines = [m[2] for job in report["jobs"] for m in job["messages"] if m[1] == "logEngine"]
    if shutil.which("cc") or shutil.which("gcc"):
        assert engines[0].startswith("engine native"), engines
    else:  # no compiler at build time: the Python lowering
        assert engines[0].startswith("engine python"), engines
    assert engines[1].startswith("engine python") and engines[2].startswith("engine xla")

    for drive, job, label in ((clean, jobs[0], "native"), (clean, jobs[1], "python"), (clean, jobs[2], "xla"),
                              (faulty, jobs[3], "faulty drive, discard_bad_samples=false")):
        out = dict(np.load(job["out"]))
        n = job.get("n") or len(drive.inputs.time_s)
        if job is not jobs[3]:  # with discard_bad_samples=false bad samples are stepped and counted
            assert out["status"][:n].all(), f"{label}: a sample was discarded"
        cols = estimate_drive(params, drive)
        ref = jaxmodel.run(params, drive.inputs)
        _compare(out, cols, ref, n, label)
    # the faulty drive's NaN compass samples were logged as warnings, not discarded
    warnings = [m for m in report["jobs"][3]["messages"] if m[0] == "WARNING" and m[1] == "logBadInput"]
    assert warnings


# ----------------------------------------------------------------------------------------------
# state, reset, two instances, bad input, bad parameters (fmu.selfcheck in a subprocess)
# ----------------------------------------------------------------------------------------------
SELFCHECK = """
import json, sys
from fmu.selfcheck import check_all, failures
res = check_all(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 and sys.argv[2] != "default" else None)
print(json.dumps({"results": res, "failures": failures(res)}, default=str))
"""


@pytest.fixture(scope="module")
def selfcheck(fmus):
    return run_py(SELFCHECK, fmus["estimator"], "default")


def test_state_save_restore_is_bit_identical(selfcheck):
    r = selfcheck["results"]["save_restore"]
    assert r["restored_bit_identical"] and r["deserialized_bit_identical"]
    assert r["state_is_json_with_hex_floats"] and r["state_size"] > 20


def test_reset(selfcheck):
    assert selfcheck["results"]["reset"]["reset_bit_identical"]


def test_two_instances_are_independent(selfcheck):
    r = selfcheck["results"]["two_instances"]
    assert r["A_equals_solo"] and r["B_equals_solo"] and r["A_differs_from_B"]


@pytest.mark.parametrize("case", ["compass_nan", "compass_inf", "counter_backwards", "counter_jump", "step_zero",
                                  "step_negative", "step_nan", "time_backwards"])
def test_bad_input_is_skipped_counted_logged_and_harmless(selfcheck, case):
    """Skipped with the state unharmed, counted, a categorised warning, and answered fmi2OK (pythonfmu
    can answer only OK or Discard, and Discard reports "terminated" for good): the run goes on."""
    r = selfcheck["results"]["bad_inputs"][case]
    assert r["skipped"] and r["counted"], r["messages"]
    assert r["categorised"], r["messages"]
    assert r["status"] == "OK" and not any(m[0] == "DISCARD" for m in r["messages"])
    assert r["state_unchanged"] and r["outputs_held"]
    assert r["continues_as_if_never_sent"]


def test_setting_a_fixed_parameter_or_unknown_variable_is_an_error(selfcheck):
    r = selfcheck["results"]["access"]
    for case in ("fixed_parameter", "unknown_variable"):
        assert r[case]["error_logged"], r[case]
    assert r["B_unchanged"]


def test_persistent_counter_jump_is_accepted_as_a_reset(selfcheck):
    r = selfcheck["results"]["bad_inputs"]["counter_reset"]
    assert r["statuses"] == ["SKIPPED", "STEPPED", "STEPPED", "STEPPED", "STEPPED"]
    assert any(m[0] == "WARNING" and "counter reset" in m[2] for m in r["messages"])


def test_lenient_mode_steps_bad_compass_with_a_warning(selfcheck):
    r = selfcheck["results"]["bad_inputs"]["lenient_compass_nan"]
    assert r["stepped"] and r["discarded_samples"] == 1
    assert any(m[0] == "WARNING" and m[1] == "logBadInput" for m in r["messages"])


def test_a_wheel_counter_that_stopped_is_logged_once_with_its_end(selfcheck):
    """A left counter stopped for 2 s at 16 m/s while the right counts on: one logBadInput warning naming it (from
    the last sample before the stop) once it lasted STOPPED_MIN_S, one information at its end; nothing without it."""
    r = selfcheck["results"]["stopped_counter"]
    assert r["warned_once"] and r["end_reported"] and r["clean_quiet"], r["messages"]
    since = re.search(r"since t=([-+.e0-9]+) s", r["messages"][0][2])
    assert since and float(since.group(1)) == pytest.approx(11.9) and r["messages"][0][1] == "logBadInput", r["messages"]


@pytest.mark.parametrize("key", ["P", "T_F", "B", "sensor_axle", "mode"])
def test_invalid_parameters_are_refused_naming_them(selfcheck, key):
    r = selfcheck["results"]["bad_parameters"][key]
    assert r["named"], r["messages"]
    # pythonfmu cannot answer fmi2Error (any exception is fmi2Fatal and frees the slave): the message
    # has error status, no step is ever OK (fmi2Discard), and the outputs are NaN
    assert r["init_error"] is None and r["stepped"] is False and r["outputs_nan"]


def test_selfcheck_passes_with_every_engine(fmus, selfcheck):
    assert selfcheck["failures"] == []
    for engine in ("python",):
        res = run_py(SELFCHECK, fmus["estimator"], engine)
        assert res["failures"] == [], engine
        assert any(f"engine {engine}" in m[2] for m in res["results"]["engine_log"])


# ----------------------------------------------------------------------------------------------
# host isolation: the FMU's own jaxmodel, the host's JAX config untouched
# ----------------------------------------------------------------------------------------------
ISOLATION = """
import json, sys
sys.path.insert(0, sys.argv[1])
import jaxmodel as host_jaxmodel            # the host's own, different, jaxmodel
import jax
import jax.numpy as jnp
jax.config.update("jax_debug_nans", True)   # a host setting the FMU must neither need nor change
before = (jax.config.jax_enable_x64, jax.config.jax_debug_nans)
import numpy as np
from fmu.cosim import replay
data = np.load(sys.argv[2])
cols = {k: data[k][:300] for k in data.files}
for engine in ("auto", "python", "xla"):
    res = replay(sys.argv[3], cols, {"engine": engine})
    np.savez(sys.argv[4] + f"_{engine}.npz", **{k: v for k, v in res.items() if k != "messages"})
after = (jax.config.jax_enable_x64, jax.config.jax_debug_nans)
print(json.dumps({"before": before, "after": after, "host_dtype": str(jnp.zeros(1).dtype),
                  "host_module_kept": sys.modules["jaxmodel"] is host_jaxmodel and host_jaxmodel.MARK == "host",
                  "private": sorted(m for m in sys.modules if m.startswith("_odocompass_jaxmodel_"))[:1]}))
"""


def test_fmu_uses_its_own_jaxmodel_and_leaves_host_jax_config_alone(fmus, tmp_path):
    import jaxmodel

    fake = tmp_path / "host_site" / "jaxmodel"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text(
        'MARK = "host"\n'
        'def __getattr__(name):\n'
        '    raise RuntimeError(f"the FMU used the host\'s jaxmodel ({name})")\n')
    drive, path = _simulated_drive(tmp_path, "iso", scenario="urban", duration=40.0, seed=2)
    out = run_py(ISOLATION, fake.parent, path, fmus["estimator"], tmp_path / "iso")
    assert out["before"] == [False, True] and out["after"] == [False, True]
    assert out["host_dtype"] == "float32"
    assert out["host_module_kept"]
    assert out["private"] and out["private"][0].startswith("_odocompass_jaxmodel_")
    ref = jaxmodel.run(custom_params(), jaxmodel.Inputs(*[np.asarray(a)[:300] for a in drive.inputs]))
    for engine in ("auto", "python", "xla"):
        got = dict(np.load(tmp_path / f"iso_{engine}.npz"))
        assert float(np.max(np.abs(wrap(got["heading"] - np.asarray(ref.heading))))) <= 1e-9, engine


TWO_BUILDS = """
import json, sys
import numpy as np
from fmu.cosim import Slave, replay
data = np.load(sys.argv[1])
cols = {k: data[k][:300] for k in data.files}
a = Slave(sys.argv[2], "A")     # both scripts are called OdoCompass.py
b = Slave(sys.argv[3], "B")
ra = replay(None, cols, slave=a)
rb = replay(None, cols, slave=b)
a.close(); b.close()
np.savez(sys.argv[4], a=ra["heading"], b=rb["heading"])
print(json.dumps({"ok": True}))
"""


def test_two_builds_with_different_start_values_in_one_process(fmus, tmp_path):
    import jaxmodel
    from fmu.build import build_estimator

    other = {"P": 0.1, "B": 2.6, "T_F": 1.5, "variation_deg": -3.0}
    b = build_estimator(tmp_path / "other" / "OdoCompass.fmu", other, native_configs=({"mode": "complementary"},))
    drive, path = _simulated_drive(tmp_path, "two", scenario="urban", duration=40.0, seed=3)
    run_py(TWO_BUILDS, path, fmus["estimator"], b, tmp_path / "two_out.npz")
    got = np.load(tmp_path / "two_out.npz")
    inputs = jaxmodel.Inputs(*[np.asarray(x)[:300] for x in drive.inputs])
    ref_a = jaxmodel.run(custom_params(), inputs).heading
    ref_b = jaxmodel.run(jaxmodel.make_params(other), inputs).heading
    assert float(np.max(np.abs(wrap(got["a"] - np.asarray(ref_a))))) <= 1e-9
    assert float(np.max(np.abs(wrap(got["b"] - np.asarray(ref_b))))) <= 1e-9
    assert float(np.max(np.abs(wrap(got["a"] - got["b"])))) > 1e-3


def test_every_jaxmodel_input_and_output_has_fmu_metadata():
    """A new field of jaxmodel.Inputs/Outputs needs its FMU unit and description in fmu/model_description.py."""
    import jaxmodel
    from fmu.build import INPUT_META, OUTPUT_META

    assert [f for f in jaxmodel.Inputs._fields if f != "time_s" and f not in INPUT_META] == []
    assert [f for f in jaxmodel.Outputs._fields if f not in OUTPUT_META] == []


NO_JAX = """
import json, sys
from fmu.cosim import Slave
s = Slave(sys.argv[1], "nojax")
s.initialize(0.0, None, {"compass_x": 20.0, "compass_y": 1.0})
heading = s.get(["heading"])["heading"]
s.set({"left_pulses": 10, "right_pulses": 10})
stepped = s.step(0.0, 0.1)
status = s.last_status
msgs = [m for m in s.messages if m[0] != "OK"]
s.close()
print(json.dumps({"heading": repr(heading), "stepped": stepped, "status": status, "messages": msgs}))
"""


def test_pythonfmu_fmu_without_jax_is_never_ok_with_nan_outputs(fmus, tmp_path):
    """A host without jax: the error is logged with error status and no step answers OK."""
    fake = tmp_path / "nojax" / "jax"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError(\"No module named 'jax' (hidden by the test)\")\n")
    out = run_py(NO_JAX, fmus["estimator"], env_extra={"PYTHONPATH": f"{fake.parent}:{REPO}"})
    assert out["heading"] == "nan" and out["stepped"] is False and out["status"] == "DISCARD", out
    assert any(m[0] == "ERROR" and "jax" in m[2] for m in out["messages"]), out["messages"]
