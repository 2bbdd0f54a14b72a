"""odocompass fleet identify / evaluate on a real local Ray cluster (issue 13).

One cluster (``ray.init(num_cpus=1)``) is shared by every test of the module; the fleet commands
find it initialised and use it as it is.  One CPU: the suite already runs two pytest workers on this 2-core machine,
and the fixture's two tasks (the same padded program) then run one after the other, the second loading the first's
compiled program from the run's cache instead of compiling it beside it (the fixture alone, beside a benchmark: 129 s
with two CPUs, 108 s with one; the whole suite's profile had it at 286 s with two).  The fleet is small: four
simulated vehicles with known parameters (two short drives each) and one vehicle whose log is corrupt.  One
``fleet identify`` run (a module fixture) is inspected by several tests; rerunning it checks the resume.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray")

import jaxmodel as jm  # noqa: E402
from identification.cli import main as cli  # noqa: E402
from identification.drive_log import write_drive  # noqa: E402
from identification.simulate import simulate  # noqa: E402

START = dict(P=0.125, B=2.7, T_F=1.55, a=0.0)
# T_F a few percent off the start, a from 0; no dpp mismatch, so T_F,a is the whole story
VEHICLES = {
    "car-01": dict(T_F=1.59, a=3.0e-4),
    "car-02": dict(T_F=1.52, a=4.5e-4),
    "car-03": dict(T_F=1.575, a=2.0e-4),
    "car-04": dict(T_F=1.53, a=5.0e-4),
}
PLAN = (("mixed", 240.0), ("urban", 180.0))
FIT = "T_F,a"


@pytest.fixture(scope="module")
def ray_cluster():
    """A local cluster for this module only: shut down after it, so the tests that follow compile
    their XLA programs without Ray's threads in the process (CI once crashed in XLA's compiler there).  The workers
    keep the suite's XLA_FLAGS (conftest: the backend optimisation off, which compiles faster) beside one thread."""
    from identification.fleet_ray import XLA_ONE_THREAD

    started = not ray.is_initialized()
    if started:
        ray.init(address="local", num_cpus=1, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {XLA_ONE_THREAD}".strip()}})
    yield
    if started:
        ray.shutdown()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory, ray_cluster):
    """Drives, manifest, start file, and one `fleet identify` run: (folder, exit code, wall s)."""
    root = tmp_path_factory.mktemp("fleet")
    rows = ["vehicle_id,path,role"]
    for k, (vid, truth) in enumerate(VEHICLES.items()):
        params = dict(START, **truth)
        for i, (sc, dur) in enumerate(PLAN):
            write_drive(root / f"{vid}_{sc}.csv", simulate(sc, dur, seed=10 * k + i, params=params)[0])
            rows.append(f"{vid},{vid}_{sc}.csv,train")
    (root / "broken_mixed.csv").write_text("time_s,left_pulses,right_pulses,compass_x,compass_y\n0,0,0,1,\x00\x00\n")
    rows.append("broken,broken_mixed.csv,train")
    (root / "manifest.csv").write_text("\n".join(rows) + "\n")
    jm.save_params(root / "start.json", jm.make_params(START))
    t0 = time.perf_counter()
    rc = cli(["-q", "fleet", "identify", str(root / "manifest.csv"), "--params", str(root / "start.json"),
              "--out", str(root / "out"), "--fit", FIT, "--batch", "3"])
    return root, rc, time.perf_counter() - t0


def _summary(root: Path) -> dict[str, dict]:
    import pyarrow.parquet as pq

    return {r["vehicle_id"]: r for r in pq.read_table(root / "out" / "summary.parquet").to_pylist()}


@pytest.mark.slow
def test_fleet_recovers_each_vehicle_and_reports_the_corrupt_log(fleet):
    root, rc, _ = fleet
    assert rc == 3  # some vehicle ended error
    rows = _summary(root)
    assert list(rows) == list(VEHICLES) + ["broken"]  # manifest order
    bad = rows["broken"]
    assert bad["status"] == "error" and "broken_mixed.csv" in bad["error"] and "\n" not in bad["error"]
    assert not (root / "out" / "broken.json").exists()
    for vid, truth in VEHICLES.items():
        row = rows[vid]
        assert row["status"] in ("ok", "warning"), row["error"]
        # 7 minutes of driving per vehicle: T_F to the 0.5 %; a (from 0) to its standard error
        assert abs(row["T_F"] / truth["T_F"] - 1.0) < 0.005, (vid, row["T_F"])
        assert abs(row["T_F"] - truth["T_F"]) < 4 * row["T_F_std_error"], (vid, row["T_F"], row["T_F_std_error"])
        assert abs(row["a"] - truth["a"]) < 4 * row["a_std_error"], (vid, row["a"], row["a_std_error"])
        assert abs(row["a"] / truth["a"] - 1.0) < 0.5, (vid, row["a"])
        assert row["train_rmse_after_deg"] < row["train_rmse_before_deg"]
    # the CSV twin has the same rows and columns
    import csv

    with open(root / "out" / "summary.csv", newline="") as fh:
        csv_rows = list(csv.DictReader(fh))
    assert [r["vehicle_id"] for r in csv_rows] == list(rows)
    assert {"T_F", "T_F_std_error", "a", "a_std_error", "warnings", "error"} <= set(csv_rows[0])
    assert (root / "out" / "parameters.png").stat().st_size > 1000


@pytest.mark.slow
def test_fitted_file_is_a_parameter_file_for_estimate(fleet, tmp_path):
    root, _, _ = fleet
    fitted = root / "out" / "car-01.json"
    data = json.loads(fitted.read_text())
    assert data["report"]["fleet"]["status"] in ("ok", "warning")
    assert data["report"]["fit"] == ["T_F", "a"] and "parameters" in data["report"]
    rc = cli(["-q", "estimate", str(root / "car-01_urban.csv"), "--params", str(fitted), "--out",
              str(tmp_path / "est.csv")])
    assert rc == 0 and (tmp_path / "est.csv").stat().st_size > 0


@pytest.mark.slow
def test_rerun_resumes_skipping_finished_vehicles(fleet):
    root, _, first_wall = fleet
    out = root / "out"
    stamps = {vid: (out / f"{vid}.json").stat().st_mtime_ns for vid in VEHICLES}
    t0 = time.perf_counter()
    rc = cli(["-q", "fleet", "identify", str(root / "manifest.csv"), "--params", str(root / "start.json"),
              "--out", str(out), "--fit", FIT, "--batch", "3"])
    wall = time.perf_counter() - t0
    assert rc == 3  # the broken vehicle is retried, and is still broken
    assert {vid: (out / f"{vid}.json").stat().st_mtime_ns for vid in VEHICLES} == stamps
    rows = _summary(root)
    assert all(rows[vid]["resumed"] for vid in VEHICLES) and not rows["broken"]["resumed"]
    assert wall < first_wall / 2


@pytest.mark.slow
def test_fleet_evaluate_with_each_vehicles_parameters(fleet):
    import pyarrow.parquet as pq

    root, _, _ = fleet
    rc = cli(["-q", "fleet", "evaluate", str(root / "manifest.csv"), "--params", str(root / "out"),
              "--out", str(root / "eval"), "--mode", "odometer", "--calibration", "off"])
    assert rc == 3  # the broken vehicle has neither a parameter file nor a readable log
    rows = pq.read_table(root / "eval" / "metrics.parquet").to_pylist()
    assert len(rows) == 2 * len(VEHICLES) + 1
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == 2 * len(VEHICLES)
    for r in ok:
        assert r["distance_m"] > 100 and r["n_samples"] > 1000 and r["ref_samples"] > 0
        assert 0 < r["rmse_deg"] < 10 and r["params"].endswith(f"{r['vehicle_id']}.json")
        assert r["dpp_source"] == "file" and r["dpp_left_m"] > 0  # identified files give the dpp
    (bad,) = [r for r in rows if r["status"] == "error"]
    assert bad["vehicle_id"] == "broken" and "broken.json" in bad["error"]


def test_task_runs_with_one_xla_thread_and_a_dead_worker_is_retried(ray_cluster, tmp_path):
    """Ray's worker environment has one XLA CPU thread; a worker killed mid-task is retried."""
    from identification import fleet_ray

    marker = tmp_path / "died-once"

    def task(payload):
        fleet_ray.worker_setup()
        if not marker.exists():
            marker.write_text("x")
            os._exit(1)  # the worker process dies, as if killed
        return os.environ.get("XLA_FLAGS", "")

    results = []
    remote = ray.remote(num_cpus=1, max_retries=fleet_ray.MAX_RETRIES)(task)
    fleet_ray.run_tasks(remote, [0], 1, [1], lambda p, r: results.append(r), "test", False)
    assert marker.exists()
    assert results and not isinstance(results[0], BaseException), results
    assert "xla_cpu_multi_thread_eigen=false" in results[0]


@pytest.mark.parametrize("content, needle", [
    ("vehicle_id,path\ncar,a.csv\n", "missing column role"),
    ("vehicle_id,path,role\n../x,a.csv,train\n", "line 2: column vehicle_id '../x'"),
    ("vehicle_id,path,role\ncar,a.csv,test\n", "line 2: column role is 'test'"),
    ("vehicle_id,path,role\ncar,a.csv,train\ncar,a.csv,train\n", "line 3: vehicle car lists a.csv again"),
    ("vehicle_id,path,role\n,a.csv,train\n", "line 2: column vehicle_id is empty"),
])
def test_bad_manifest_is_one_line_exit_2_before_any_work(tmp_path, capsys, content, needle):
    manifest = tmp_path / "m.csv"
    manifest.write_text(content)
    jm.save_params(tmp_path / "start.json", jm.make_params(START))
    rc = cli(["fleet", "identify", str(manifest), "--params", str(tmp_path / "start.json"), "--out",
              str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and "Traceback" not in err
    assert err.startswith("odocompass: error: ") and needle in err and str(manifest) in err
    assert not (tmp_path / "out").exists()


def test_missing_manifest_and_bad_params_exit_2(tmp_path, capsys):
    rc = cli(["fleet", "identify", str(tmp_path / "nope.csv"), "--params", "x.json", "--out", str(tmp_path / "o")])
    assert rc == 2 and "nope.csv: manifest not found" in capsys.readouterr().err
    (tmp_path / "m.csv").write_text("vehicle_id,path,role\ncar,a.csv,train\n")
    (tmp_path / "p.json").write_text('{"T_F": 1.5, "bogus": 1}')
    rc = cli(["fleet", "identify", str(tmp_path / "m.csv"), "--params", str(tmp_path / "p.json"), "--out",
              str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "p.json" in err and "bogus" in err and err.count("\n") == 1


def test_bucket_length_pads_little_and_shares_shapes():
    from identification.fleet_fit import bucket_length

    for n in (2, 63, 64, 100, 1000, 6000, 6001, 36000):
        b = bucket_length(n)
        assert b >= n and (b - n) <= max(0.125 * n, 64)
    assert len({bucket_length(n) for n in range(5800, 6100)}) <= 2


def test_batched_optimiser_matches_identifys_per_vehicle():
    """minimize_batch with L-BFGS directions takes each vehicle along identify's own optimiser path
    (one optax state per vehicle); Gauss-Newton directions reach the same optima in fewer iterations."""
    from identification.fleet_optimize import minimize_batch
    from identification.optimize import minimize

    rng = np.random.default_rng(3)
    V, dim = 4, 3
    A = np.stack([np.eye(dim) * (1 + 10 * v) + 0.3 * np.ones((dim, dim)) for v in range(V)])
    b = rng.normal(size=(V, dim))

    def one(v, z):
        z = np.asarray(z)
        return (0.5 * z @ A[v] @ z - b[v] @ z + 0.25 * np.sum(z ** 4), A[v] @ z - b[v] + z ** 3,
                A[v] + np.diag(3 * z ** 2))

    def batch(z):
        outs = [one(v, z[v]) for v in range(V)]
        return np.array([o[0] for o in outs]), np.stack([o[1] for o in outs]), np.stack([o[2] for o in outs])

    res = minimize_batch(batch, np.zeros((V, dim)), direction="lbfgs", gtol=1e-8)
    gn = minimize_batch(batch, np.zeros((V, dim)), direction="gauss-newton", gtol=1e-8)
    for v in range(V):
        single = minimize(lambda z, v=v: one(v, z), np.zeros(dim), gtol=1e-8)
        assert np.allclose(res.z[v], single.z, atol=1e-10) and res.iterations[v] == single.iterations
        assert np.allclose(gn.z[v], single.z, atol=1e-6) and gn.iterations[v] <= single.iterations
    assert res.converged.all() and gn.converged.all()
    # a vehicle whose objective is not finite at the start fails alone
    def poisoned(z):
        val, g, h = batch(z)
        val[1] = np.nan
        return val, g, h

    bad = minimize_batch(poisoned, np.zeros((V, dim)), gtol=1e-8)
    assert bad.failed.tolist() == [False, True, False, False] and "not finite" in bad.reason[1]
    assert np.allclose(bad.z[0], gn.z[0], atol=1e-6)


def test_parquet_manifest_and_fingerprint(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from identification.fleet_manifest import fingerprint, read_manifest

    (tmp_path / "d1.csv").write_text("x")
    pq.write_table(pa.table({"vehicle_id": ["a", "a", "b"], "path": ["d1.csv", "d2.csv", str(tmp_path / "d3.csv")],
                             "role": ["train", "validate", "TRAIN"], "note": ["", "", ""]}), tmp_path / "m.parquet")
    vehicles = read_manifest(tmp_path / "m.parquet")
    assert list(vehicles) == ["a", "b"]
    assert vehicles["a"].train == [tmp_path / "d1.csv"] and vehicles["a"].validate == [tmp_path / "d2.csv"]
    settings = {"fit": ["T_F"]}
    fp = fingerprint(vehicles["a"], settings)
    assert fp == fingerprint(vehicles["a"], settings) and fp != fingerprint(vehicles["a"], {"fit": ["a"]})
    (tmp_path / "d1.csv").write_text("changed")  # another size: the vehicle is fitted again
    assert fingerprint(vehicles["a"], settings) != fp


def test_fleet_evaluate_runs_a_vehicle_nobody_gave_as_estimate_does(tmp_path):
    """A parameter file without the vehicle (only the compass's calibration) switches on the turn-scale state of
    ``jaxmodel.UNIDENTIFIED_VEHICLE`` and the dpp fit from the compass in ``fleet evaluate`` as in ``estimate`` (one
    place decides each: diagnostics.estimation_params, wheel_scales.dpp_unknown); a file with a dpp and a track keeps
    the defaults."""
    from identification.fleet_evaluate import _vehicle_params

    (tmp_path / "car-01.json").write_text(json.dumps({"variation_deg": 2.0}))
    (tmp_path / "car-02.json").write_text(json.dumps({"T_F": 1.55, "a": 1.2e-4, "dpp_left": 0.021, "dpp_right": 0.021}))
    per_vehicle = _vehicle_params(tmp_path, ["car-01", "car-02"])
    nobody, _, err1, fit_dpp1 = per_vehicle["car-01"]
    given, _, err2, fit_dpp2 = per_vehicle["car-02"]
    assert err1 is None and err2 is None and fit_dpp1 and not fit_dpp2
    for key, value in jm.UNIDENTIFIED_VEHICLE.items():
        assert nobody[key] == pytest.approx(value)
    default = jm.params_to_dict(jm.make_params())
    assert given["filter_scale_sigma0"] == pytest.approx(default["filter_scale_sigma0"])
    assert default["filter_scale_sigma0"] != pytest.approx(jm.UNIDENTIFIED_VEHICLE["filter_scale_sigma0"])
    single = _vehicle_params(tmp_path / "car-01.json", ["car-07"])["car-07"][0]
    assert single["filter_scale_sigma0"] == pytest.approx(jm.UNIDENTIFIED_VEHICLE["filter_scale_sigma0"])


@pytest.mark.slow
def test_fleet_evaluate_task_finds_the_dpp_a_file_does_not_give(tmp_path):
    """``fleet evaluate``'s task on an independent-simulator drive (dpp 0.041 m, twice the nominal) with a file that
    has only the compass's calibration: the dpp found from the drive's compass, as ``estimate`` finds them, and said
    in the metrics (dpp_source)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from independent_drives import independent_sim

    from identification.fleet_evaluate import _vehicle_params, evaluate_task

    csv_path, params_path = independent_sim.make_drive("urban", 1, str(tmp_path))
    truth = json.loads(Path(params_path).read_text())
    bare = Path(independent_sim.write_no_vehicle_params(params_path))
    params, pfile, err, fit_dpp = _vehicle_params(bare, ["car"])["car"]
    item = {"vehicle_id": "car", "path": csv_path, "role": "validate", "params": params, "params_file": pfile,
            "fit_dpp": fit_dpp, "error": err}
    (row,) = evaluate_task({"drives": [item], "config": {}})
    assert row["status"] == "ok", row["error"]
    assert row["dpp_source"] == "compass"
    assert row["dpp_left_m"] == pytest.approx(truth["dpp_left"], rel=0.05)
    assert row["rmse_deg"] < 2.0
