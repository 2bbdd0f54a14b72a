"""Drives of the independent simulator (bench/independent_sim.py) for the tests: the estimate's heading error
against the simulator's truth, with the parameters a user who has not identified the vehicle has."""

import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import independent_sim  # noqa: E402  (the tests simulate with it and patch its LOG_EVERY)

import jaxmodel as jm  # noqa: E402
from identification.diagnostics import checked_params  # noqa: E402
from identification.drive_log import read_drive  # noqa: E402
from identification.estimate import estimate_drive  # noqa: E402

__all__ = ["heading_error_deg", "independent_sim", "rmse_after_first_minute", "unidentified_params"]


def unidentified_params(params_path):
    """The parameter file as ``odocompass estimate`` reads it (``for_unidentified_vehicle``)."""
    params, extra = checked_params(params_path)
    params, _ = jm.for_unidentified_vehicle(params, extra["keys"])
    return params


def heading_error_deg(path, params, config=jm.Config()):
    """(time s, heading error deg wrapped to +-180) of ``config``'s estimate of the drive at ``path`` against its
    ``.truth.csv``."""
    cols = estimate_drive(params, read_drive(path), config)
    with open(Path(path).with_suffix(".truth.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time_s"]) for r in rows])
    truth = np.array([float(r["heading_unwrapped_deg"]) for r in rows])
    return t, (np.asarray(cols["heading_deg"]) - truth + 180.0) % 360.0 - 180.0


def rmse_after_first_minute(t, err):
    """Heading RMSE (deg) after the first minute of ``heading_error_deg``'s (time s, error deg)."""
    return float(np.sqrt(np.mean(err[t >= 60.0] ** 2)))
