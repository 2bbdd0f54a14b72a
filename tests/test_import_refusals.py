"""Issue 11: the importers refuse sources with NaN or gaps they cannot bridge (one line naming the
file, row and time, exit 2, nothing written), and the demo writes only under its --out-dir."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from identification import cli
from identification import importers as im
from identification.errors import OdoCompassError


def test_refuse_unbridgeable_names_row_time_and_gap():
    t = np.arange(0.0, 10.0, 0.01)
    v = np.ones((t.size, 4))
    im.refuse_unbridgeable("w", t, v, 0.0, 10.0, "wheel speed")  # clean: accepted
    bad = v.copy()
    bad[300:310, 1] = np.nan
    with pytest.raises(OdoCompassError, match=r"^w: 10 wheel speed samples are NaN or infinite \(first at row 301, t = 3\.000 s\)"):
        im.refuse_unbridgeable("w", t, bad, 0.0, 10.0, "wheel speed")
    im.refuse_unbridgeable("w", t, bad, 5.0, 10.0, "wheel speed")  # outside the span used: no matter
    gap = np.concatenate([t[:400], t[600:]])
    with pytest.raises(OdoCompassError, match=r"gap of 2\.010 s \(t = 3\.990 to 6\.000 s\)"):
        im.refuse_unbridgeable("w", gap, np.ones((gap.size, 4)), 0.0, 10.0, "wheel speed")


@pytest.fixture
def comma_copy(real_data_dir, tmp_path):
    src = real_data_dir / "comma2k19_example"
    if not src.is_dir():
        pytest.skip(f"comma2k19 example segment not available: {src} is absent")
    dst = tmp_path / "segment"
    shutil.copytree(src, dst)
    return dst


def test_import_comma2k19_with_nan_wheel_speeds_exit_2_nothing_written(comma_copy, tmp_path, capsys):
    values = comma_copy / im.COMMA_FILES["wheel_v"]
    arr = np.load(values)
    arr[1000:1010, 0] = np.nan
    with open(values, "wb") as fh:
        np.save(fh, arr)
    before = values.read_bytes()
    old = tmp_path / "out.csv"
    old.write_text("previous import\n")
    rc = cli.main(["import", "comma2k19", str(comma_copy), "--out", str(old)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "NaN" in err and "row 1001" in err, err
    assert old.read_text() == "previous import\n" and values.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv", "segment"]


def test_demo_puts_its_fmus_under_out_dir(tmp_path, monkeypatch):
    """The demo's FMU step builds and co-simulates under --out-dir (nothing in ./build)."""
    import fmu.build
    import fmu.cosim
    from identification import demo

    seen = []

    def fake_build(out, params):
        seen.append(Path(out))
        return Path(out)

    def fake_cosim(out_dir, estimator_fmu, stop_time, fmu_dir, true_params):
        seen.extend([Path(out_dir), Path(estimator_fmu), Path(fmu_dir)])
        return {"end_time": stop_time, "rmse_deg": 0.0, "plot": str(Path(out_dir) / "p.png")}

    monkeypatch.setattr(fmu.build, "build_estimator", fake_build)
    monkeypatch.setattr(fmu.cosim, "demo_cosimulation", fake_cosim)
    monkeypatch.chdir(tmp_path)
    out_dir = tmp_path / "elsewhere" / "demo"
    demo.cosimulate(out_dir, out_dir / "identified.json", {}, stop_time=1.0)
    assert seen and all(p.resolve().is_relative_to(out_dir.resolve()) for p in seen), seen
    assert not (tmp_path / "build").exists()
