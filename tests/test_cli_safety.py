"""Issue 11: every command is safe with the user's files and says clearly what it cannot do.

One parametrised case per bad request: exit code 2, exactly one line ``odocompass: error: ...``
naming what is wrong, every input file byte for byte unchanged, and nothing computed (the
checks come before the work, so each case takes milliseconds).  Plus: unexpected errors (exit 1,
one line, ``--debug``), ``--version``, ``--help`` (defaults, units, ``--fit`` syntax, output
formats), ``-q``, and the atomic writers of ``identification.outputs``.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest

import jaxmodel as jm
from identification import cli, outputs
from identification.drive_log import write_drive
from identification.simulate import simulate

UNWRITABLE = Path("/proc/odocompass-no-such-dir")  # /proc refuses new files, even for root


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("safety")
    cols, _ = simulate("urban", 20.0, seed=3)
    write_drive(d / "drive.csv", cols)
    write_drive(d / "val.csv", cols)
    jm.save_params(d / "params.json", jm.make_params())
    (d / "latin1.json").write_bytes(b'{"B": 2.7, "note": "caf\xe9"}')
    (d / "dup.json").write_text('{"B": 2.7, "T_F": 1.5, "B": 2.8}')
    (d / "frac.json").write_text('{"counter_modulus": 65536.5}')
    (d / "huge.json").write_text('{"B": 1e308}')
    (d / "nan.json").write_text('{"B": NaN}')
    (d / "dpp0.json").write_text('{"dpp_left": 0}')
    (d / "a_neg.json").write_text('{"a": -1e-4}')
    (d / "folder").mkdir()
    (d / "plots_file").write_text("not a folder\n")
    (d / "old.csv").write_text("precious,data\n1,2\n")
    (d / "sim.truth.json").write_text(json.dumps({"params": {"B": 2.8}, "scenario": "urban", "seed": 1,
                                                  "truth_csv": "sim.truth.csv", "drive": "sim.csv"}))
    os.symlink(d / "drive.csv", d / "link.json")
    os.symlink(d / "drive.csv", d / "link.csv")
    return d


# (argv with {d} for the folder, fragments the one line must contain)
CASES = {
    "identify --out is the training drive":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/drive.csv"], ["drive log"]),
    "identify --out is a --validate drive":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/val.csv", "--validate",
          "{d}/val.csv"], ["validation drive log"]),
    "identify --out is --params":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/params.json"],
         ["parameter file itself"]),
    "identify --out is a symlink to the drive":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/link.json"], ["same file"]),
    "identify --out in an unwritable folder":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", f"{UNWRITABLE}/fit.json"],
         ["not writable"]),
    "identify --out under a file":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/old.csv/fit.json"],
         ["is a file"]),
    "identify --out is a folder":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/folder"], ["folder"]),
    "identify --plots is a file":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/fit.json", "--plots",
          "{d}/plots_file"], ["--plots", "is a file"]),
    "identify parameter error names the file":
        (["identify", "{d}/drive.csv", "--params", "{d}/huge.json", "--out", "{d}/fit.json"],
         ["huge.json", "B=1e+308"]),
    "identify start value a < 0 names the file":
        (["identify", "{d}/drive.csv", "--params", "{d}/a_neg.json", "--out", "{d}/fit.json"],
         ["a_neg.json", "a="]),
    "identify --fit with an unknown key":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/fit.json", "--fit", "P,Q"],
         ["'Q'"]),
    "build-fmu --out is --params":
        (["build-fmu", "--params", "{d}/params.json", "--out", "{d}/params.json"], ["parameter file itself"]),
    "build-fmu --out is a csv":
        (["build-fmu", "--out", "{d}/old.csv"], [".fmu"]),
    "build-fmu --out is a folder":
        (["build-fmu", "--out", "{d}/folder"], ["folder"]),
    "build-fmu --out in an unwritable folder":
        (["build-fmu", "--out", f"{UNWRITABLE}/x.fmu"], ["not writable"]),
    "build-fmu --params is a folder":
        (["build-fmu", "--params", "{d}/folder", "--out", "{d}/x.fmu"], ["is a folder"]),
    "build-fmu --params with a duplicate key":
        (["build-fmu", "--params", "{d}/dup.json", "--out", "{d}/x.fmu"], ["dup.json", "duplicate key 'B'"]),
    "estimate --params is a folder":
        (["estimate", "{d}/drive.csv", "--params", "{d}/folder", "--out", "{d}/est.csv"], ["is a folder"]),
    "estimate --params with a Latin-1 byte":
        (["estimate", "{d}/drive.csv", "--params", "{d}/latin1.json", "--out", "{d}/est.csv"],
         ["latin1.json", "utf-8", "0xe9"]),
    "estimate --params with a fractional counter_modulus":
        (["estimate", "{d}/drive.csv", "--params", "{d}/frac.json", "--out", "{d}/est.csv"],
         ["frac.json", "counter_modulus"]),
    "estimate --params with B = 1e308":
        (["estimate", "{d}/drive.csv", "--params", "{d}/huge.json", "--out", "{d}/est.csv"],
         ["huge.json", "B=1e+308"]),
    "estimate --params with NaN":
        (["estimate", "{d}/drive.csv", "--params", "{d}/nan.json", "--out", "{d}/est.csv"], ["nan.json", "NaN"]),
    "estimate --out is a symlink to the drive":
        (["estimate", "{d}/drive.csv", "--out", "{d}/link.csv"], ["same file"]),
    "estimate --out under a file":
        (["estimate", "{d}/drive.csv", "--out", "{d}/drive.csv/est.csv"], ["is a file"]),
    "simulate --seed -1":
        (["simulate", "--seed", "-1", "--out", "{d}/sim.csv"], ["--seed"]),
    "estimate --bogus (named by its command, stop 44)":
        (["estimate", "{d}/drive.csv", "--out", "{d}/est.csv", "--bogus"], ["estimate: unrecognized", "--bogus",
                                                                            "odocompass estimate --help"]),
    "fleet identify --bogus":
        (["fleet", "identify", "{d}/m.csv", "--params", "{d}/params.json", "--out", "{d}/fl", "--bogus"],
         ["fleet identify: unrecognized", "--bogus"]),
    "identify --out not .json (stop 44: JSON was written into fit.csv)":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/fit.csv"],
         ["fit.csv", "--out must end in .json"]),
    "identify --max-iter -5 (the message of 0, stop 44)":
        (["identify", "{d}/drive.csv", "--params", "{d}/params.json", "--out", "{d}/fit.json", "--max-iter", "-5"],
         ["--max-iter", "1 or more"]),
    "simulate --duration 0":
        (["simulate", "--duration", "0", "--out", "{d}/sim.csv"], ["--duration"]),
    "simulate --params with dpp_left 0":
        (["simulate", "--duration", "5", "--params", "{d}/dpp0.json", "--out", "{d}/sim.csv"],
         ["dpp0.json", "dpp_left"]),
    "simulate --out in an unwritable folder":
        (["simulate", "--duration", "5", "--out", f"{UNWRITABLE}/sim.csv"], ["not writable"]),
    "simulate truth file would overwrite --params":
        (["simulate", "--duration", "5", "--params", "{d}/sim.truth.json", "--out", "{d}/sim.csv"],
         ["parameter file itself"]),
    "simulate --out is the old csv's folder path":
        (["simulate", "--duration", "5", "--out", "{d}/old.csv/sim.csv"], ["is a file"]),
    "import --out is a folder":
        (["import", "husky", "{d}/drive.csv", "--out", "{d}/folder"], ["folder"]),
    "import --out is the source":
        (["import", "husky", "{d}/drive.csv", "--out", "{d}/drive.csv"], ["source"]),
    "demo --out-dir is a file":
        (["demo", "--out-dir", "{d}/old.csv"], ["--out-dir", "is a file"]),
    "unknown command":
        (["frobnicate"], ["invalid choice"]),
}


def _snapshot(d: Path) -> dict:
    return {p.name: (p.read_bytes() if p.is_file() else None) for p in sorted(d.iterdir())}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_request_one_line_exit_2_inputs_unchanged(case, files, capsys):
    argv, fragments = CASES[case]
    argv = [a.replace("{d}", str(files)) for a in argv]
    before = _snapshot(files)
    rc = cli.main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1 and lines[0].startswith("odocompass: error: "), err
    for frag in fragments:
        assert frag.lower() in lines[0].lower(), (frag, lines[0])
    assert _snapshot(files) == before, "an input or another file in the folder changed"


def test_unexpected_error_is_one_line_exit_1_with_debug_hint(monkeypatch, capsys):
    import identification.estimate as est

    def boom(args):
        raise RuntimeError("something\nbroke")

    monkeypatch.setattr(est, "main", boom)
    assert cli.main(["estimate", "x.csv", "--out", "y.csv"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("odocompass: internal error: RuntimeError: something broke")
    assert "--debug" in err
    assert cli.main(["--debug", "estimate", "x.csv", "--out", "y.csv"]) == 1
    assert "Traceback" in capsys.readouterr().err
    assert cli.main(["estimate", "x.csv", "--out", "y.csv", "--debug"]) == 1  # after the command too
    assert "Traceback" in capsys.readouterr().err


def test_version(capsys):
    assert cli.main(["--version"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("odocompass ") and any(c.isdigit() for c in out)


@pytest.mark.parametrize("command, fragments", [
    ("simulate", ["(default: 900.0)", "seconds", "(default: mixed)", "metres"]),
    ("estimate", ["(default: complementary)", ".parquet", ".mf4", "degrees"]),
    ("identify", ["comma-separated parameter keys", "P,B,T_F,a", "(default: P,B,T_F,a,T_C,D_N)", "(default: 400)"]),
    ("build-fmu", ["(default: build/OdoCompass.fmu)", ".fmu"]),
    ("import", ["comma2k19", "metres per pulse", "NaN"]),
    ("demo", ["(default: build/demo)", "FMUs"]),
])
def test_help_shows_defaults_units_and_syntax(command, fragments, capsys):
    assert cli.main([command, "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    for frag in fragments:
        assert frag in out, (command, frag)
    assert "--quiet" in out and "--debug" in out


def test_quiet_estimate_prints_nothing_but_warnings(files, tmp_path, capsys):
    est = tmp_path / "est.csv"
    assert cli.main(["-q", "estimate", str(files / "drive.csv"), "--out", str(est)]) == 0
    assert capsys.readouterr().err == ""
    assert cli.main(["estimate", str(files / "drive.csv"), "--out", str(est)]) == 0
    err = capsys.readouterr().err
    assert "skipped" in err and "\r" not in err  # no progress bar when stderr is not a terminal


def test_quiet_simulate_prints_nothing(tmp_path, capsys):
    """Before stop 44 simulate (and build-fmu) printed their summary on stdout whatever -q said."""
    out = tmp_path / "q.csv"
    assert cli.main(["-q", "simulate", "--duration", "5", "--out", str(out)]) == 0
    assert capsys.readouterr() == ("", "") and out.is_file()
    assert cli.main(["simulate", "--duration", "5", "--out", str(tmp_path / "v.csv")]) == 0
    assert "wrote" in capsys.readouterr().err


def test_simulate_params_accepts_its_own_truth_json(tmp_path, capsys):
    truth_params = dict(jm.params_to_dict(jm.make_params()), B=2.9, a=2e-4)
    first = tmp_path / "first.csv"
    cols, truth = simulate("urban", 10.0, seed=2, params=truth_params)
    from identification.simulate import write_truth
    write_drive(first, cols)
    _, truth_json = write_truth(first, truth)
    second = tmp_path / "second.parquet"
    assert cli.main(["simulate", "--duration", "10", "--seed", "2", "--params", str(truth_json),
                     "--out", str(second)]) == 0
    meta = json.loads((tmp_path / "second.truth.json").read_text())
    assert meta["params"]["B"] == 2.9 and meta["params"]["a"] == 2e-4
    loaded, _ = jm.load_params(truth_json)
    assert float(loaded.B) == 2.9
    capsys.readouterr()


# --- identification.outputs --------------------------------------------------------------------

def test_atomic_write_keeps_the_old_file_on_failure(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError):
        with outputs.atomic(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("the work failed half way")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]  # no temporary left behind
    with outputs.atomic(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".csv" and tmp != target
        tmp.write_text("new\n")
    assert target.read_text() == "new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_staged_files_appear_together_or_not_at_all(tmp_path):
    a, b = tmp_path / "d.csv", tmp_path / "d.truth.json"
    with pytest.raises(ValueError):
        with outputs.staged([a, b]) as (ta, tb):
            ta.write_text("drive")
            raise ValueError("truth failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    with outputs.staged([a, b]) as (ta, tb):
        ta.write_text("drive")
        tb.write_text("{}")
    assert a.read_text() == "drive" and b.read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.csv", "d.truth.json"]


def test_output_checks_create_nothing(tmp_path):
    deep = tmp_path / "new" / "deeper" / "fit.json"
    assert outputs.check_output_file(deep) == deep
    assert not (tmp_path / "new").exists()
    hard = tmp_path / "hard.csv"
    (tmp_path / "orig.csv").write_text("x\n")
    os.link(tmp_path / "orig.csv", hard)
    with pytest.raises(outputs.OutputError, match="same file"):
        outputs.check_output_file(hard, inputs=[("the drive log", tmp_path / "orig.csv")])


def test_a_fleet_output_that_is_an_input_log_is_refused_before_any_work(tmp_path):
    """``outputs.check_folder_files`` (fleet identify and fleet evaluate): a table the command would write into
    --out that is already one of its drive logs (here through a hard link) is refused by name; absent or other
    files pass, and nothing is created."""
    out = tmp_path / "out"
    out.mkdir()
    log = tmp_path / "drive.csv"
    log.write_text("x\n")
    os.link(log, out / "summary.csv")
    outputs.check_folder_files(out, ["metrics.parquet", "car.json"], [("the drive log", log)])
    with pytest.raises(outputs.OutputError, match=r"summary\.csv: --out would write over the drive log .*drive\.csv; "
                                                  r"choose another folder"):
        outputs.check_folder_files(out, ["summary.parquet", "summary.csv"], [("the manifest", tmp_path / "m.csv"),
                                                                             ("the drive log", log)])
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv"]


def test_save_params_is_atomic_and_refuses_nan_before_touching_the_file(tmp_path):
    path = tmp_path / "p.json"
    jm.save_params(path, jm.make_params())
    before = path.read_bytes()
    with pytest.raises(ValueError):
        jm.save_params(path, jm.make_params(), report={"bad": float("nan")})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]


def test_parameter_file_errors_are_one_line_naming_file_and_key(tmp_path):
    cases = {
        b'{"B": 2.7, "B": 2.8}': "duplicate key 'B'",
        b'{"counter_modulus": 1000.25}': "counter_modulus",
        b'\xff\xfe{"B": 2}': "not UTF-8",
        b'{"deviation_deg": "north"}': "deviation_deg",
        b'{"B": 1' + b'0' * 400 + b'}': "B",
        b'[1, 2]': "JSON object",
    }
    for i, (data, frag) in enumerate(cases.items()):
        path = tmp_path / f"p{i}.json"
        path.write_bytes(data)
        with pytest.raises(jm.ParameterError) as exc:
            p, _ = jm.load_params(path)
            jm.validate_params(p)
        msg = str(exc.value)
        assert "\n" not in msg and frag in msg, (data[:40], msg)
    ok = tmp_path / "ok.json"
    ok.write_text('{"counter_modulus": 4294967296.0, "a": 0}')
    p, _ = jm.load_params(ok)
    jm.validate_params(p)
    assert float(p.counter_modulus) == 2.0**32


def test_absurd_magnitudes_are_refused_by_name():
    for key, value in (("B", 1e308), ("T_F", 1e6), ("dpp_left", 1e3), ("D_N", 1e200)):
        with pytest.raises(jm.ParameterError, match=rf"{key}="):
            jm.validate_params(jm.make_params({key: value}))
    jm.validate_params(jm.make_params())  # the defaults pass
    # every default passes the magnitude rule whatever keys the table gains
    for spec in jm.PARAMETER_TABLE:
        if spec.key != "sensor_axle":
            assert np.all(np.abs(np.asarray(spec.default, dtype=float)) <= jm.params.MAX_MAGNITUDE), spec.key


CTRL_C_CHILD = """
import runpy, signal, sys
# Python leaves SIGINT ignored where its parent ignored it (a suite run with nohup): the user's terminal does not.
signal.signal(signal.SIGINT, signal.default_int_handler)
script = sys.argv.pop(1)
runpy.run_path(script, run_name="__main__")
"""


@pytest.mark.slow
def test_ctrl_c_while_compiling_exits_130_without_a_crash(files, tmp_path):
    """Before stop 44 Ctrl-C while XLA compiled printed 'interrupted' and then died in the interpreter's finalization
    (SIGSEGV, -11; at 2-8 s in, with the compilation cache off).  The console script (``cli.entry``) now leaves at
    once.  A run that finished before its signal says nothing; at least one must be interrupted."""
    import shutil
    import signal
    import subprocess
    import sys
    import time

    script = shutil.which("odocompass", path=str(Path(sys.executable).parent))
    assert script, "the odocompass console script is installed beside this interpreter"
    # As a user runs it: without the suite's compilation cache and its faster, unoptimised compile.
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "XLA_FLAGS")}
    env["ODOCOMPASS_CACHE_DIR"] = "off"
    codes = []
    for attempt, delay_s in enumerate((3.0, 2.0, 4.0)):
        out = tmp_path / f"k{attempt}.csv"
        argv = [sys.executable, "-c", CTRL_C_CHILD, script, "estimate", str(files / "drive.csv"), "--params",
                str(files / "params.json"), "--out", str(out), "--mode", "kalman"]
        proc = subprocess.Popen(argv, env=env, stderr=subprocess.PIPE, text=True)
        time.sleep(delay_s)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
        codes.append(proc.returncode)
        assert proc.returncode in (0, 130), (delay_s, proc.returncode, err[-500:])
        if proc.returncode == 130:
            assert err.strip().splitlines()[-1] == "odocompass: interrupted"
            assert not out.exists() and not list(tmp_path.glob(".*.part"))
    assert 130 in codes, codes


def test_the_console_script_is_cli_entry():
    import tomllib

    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert pyproject["project"]["scripts"]["odocompass"] == "identification.cli:entry"
