"""`odocompass demo` runs end to end (quick variant) and leaves its plots, tables and FMUs."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_demo_quick_runs_end_to_end(tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "identification.cli", "demo", "--quick", "--out-dir", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=1200,
                          env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name in ("heading_error.png", "identified.json", "summary.json", "cosim/fmu_cosim_heading.png"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    rmse = summary["heading_rmse_deg"]
    assert rmse["complementary"] < rmse["compass"]
    assert summary["cosimulation"]["end_time"] == pytest.approx(120.0, abs=0.11)
    assert "Identification" in proc.stdout and "FMU" in proc.stdout
