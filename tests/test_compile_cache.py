"""The command line keeps XLA's compiled programs between runs (identification/compile_cache.py)."""

import json
import os
import subprocess

import numpy as np
import pytest
from test_estimate_cli import _odocompass, drive_columns

from identification import compile_cache
from identification.drive_log import read_table, write_drive


def test_jax_own_setting_wins_and_off_switches_it_off(tmp_path):
    assert compile_cache.cache_dir({"JAX_COMPILATION_CACHE_DIR": "/somewhere"}) is None
    for off in ("", "0", "off", "OFF", " none "):
        assert compile_cache.cache_dir({"ODOCOMPASS_CACHE_DIR": off}) is None
    chosen = tmp_path / "a" / "b"
    assert compile_cache.cache_dir({"ODOCOMPASS_CACHE_DIR": str(chosen)}) == chosen and chosen.is_dir()


def test_default_is_under_the_user_cache_folder(tmp_path):
    assert compile_cache.cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "odocompass" / "jax"


def test_no_home_folder_leaves_the_cache_off(monkeypatch):
    def no_home(*args):
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr(compile_cache.Path, "home", classmethod(no_home))
    monkeypatch.setattr(compile_cache.Path, "expanduser", no_home)
    assert compile_cache.cache_dir({}) is None
    assert compile_cache.cache_dir({"ODOCOMPASS_CACHE_DIR": "~/x"}) is None


def test_a_folder_that_cannot_be_made_leaves_the_cache_off(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert compile_cache.cache_dir({"ODOCOMPASS_CACHE_DIR": str(blocker / "jax")}) is None
    assert compile_cache.cache_dir({"ODOCOMPASS_CACHE_DIR": str(blocker)}) is None
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert compile_cache.cache_dir({"ODOCOMPASS_CACHE_DIR": str(locked)}) is None


def _estimate(drive, out, cache_value, cwd):
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env.update(ODOCOMPASS_CACHE_DIR=cache_value, PYTHONWARNINGS="ignore")
    return subprocess.run(_odocompass() + ["estimate", "-q", str(drive), "--params", str(cwd / "p.json"), "--out", str(out)],
                          cwd=cwd, capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow
def test_estimate_fills_the_cache_then_gives_the_same_result_from_it(tmp_path):
    drive = write_drive(tmp_path / "drive.parquet", drive_columns(n=300))
    (tmp_path / "p.json").write_text(json.dumps({"sensor_axle": "rear", "T_R": 1.55}))
    cache = tmp_path / "cache"
    first = _estimate(drive, tmp_path / "first.csv", str(cache), tmp_path)
    assert first.returncode == 0 and first.stderr == "", first.stderr
    programs = sorted(p.name for p in cache.glob("*-cache"))
    assert programs, "no compiled program was kept"
    second = _estimate(drive, tmp_path / "second.csv", str(cache), tmp_path)
    assert second.returncode == 0 and second.stderr == "", second.stderr
    assert sorted(p.name for p in cache.glob("*-cache")) == programs  # every program came from the cache
    a, b = read_table(tmp_path / "first.csv"), read_table(tmp_path / "second.csv")
    assert list(a) == list(b)
    for column in a:
        np.testing.assert_array_equal(np.asarray(a[column]), np.asarray(b[column]), err_msg=column)
    # a cache folder that cannot be written: the same estimate, nothing said
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    third = _estimate(drive, tmp_path / "third.csv", str(blocker / "jax"), tmp_path)
    assert third.returncode == 0 and third.stderr == "", third.stderr
    c = read_table(tmp_path / "third.csv")
    np.testing.assert_array_equal(np.asarray(c["heading_deg"]), np.asarray(a["heading_deg"]))
