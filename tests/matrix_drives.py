"""Running a drive of the scenario matrix (identification.scenarios) as the matrix scores it, for the tests."""

import numpy as np

import jaxmodel as jm
from identification.drive_log import drive_from_columns
from identification.estimate import run_padded


def run_drive(drive, overrides=None, **config):
    """jaxmodel.run on the drive with its vehicle's parameters, then ``overrides``, padded to its length bucket as
    ``estimate_drive`` is (``estimate.run_padded``): the matrix's 15-minute drives differ by a few samples
    (8964-8976), and unpadded each length compiled its own program (~5.5 s of the ~6 s a drive took).  ``config``:
    Config fields."""
    log = drive_from_columns(drive.columns, source=drive.name)
    return run_padded(jm.make_params({**drive.params, **(overrides or {})}), log, jm.Config(**config))


def heading_error_deg(out, drive):
    """The heading's error against the drive's truth, per sample, wrapped (deg)."""
    return np.degrees(np.angle(np.exp(1j * (np.asarray(out.heading) - drive.truth["heading_rad"]))))


def after_first_minute(err_deg, drive):
    """The heading errors after the first minute (the part of a drive the matrix scores)."""
    return err_deg[drive.truth["time_s"] >= 60.0]


def rmse(err_deg):
    return float(np.sqrt(np.mean(err_deg ** 2)))


def rmse_after_first_minute(out, drive):
    """Heading RMSE (deg) of ``out`` after the first minute, as the matrix scores it."""
    return rmse(after_first_minute(heading_error_deg(out, drive), drive))


def default_rmse_after_first_minute(drive, overrides=None, **config):
    """Heading RMSE (deg) of the default estimator (``config``: Config fields) after the first minute, as the matrix
    scores it."""
    return rmse_after_first_minute(run_drive(drive, overrides, **config), drive)


def default_and(drive, name, overrides, **config):
    """RMSE after the first minute of the default and of the default with ``overrides`` (called ``name``)."""
    return {"default": default_rmse_after_first_minute(drive, **config),
            name: default_rmse_after_first_minute(drive, overrides, **config)}


def assert_default_beats(drive, name, overrides, without_above, fraction, **config):
    """The drive is bad without the change (``overrides`` RMSE above ``without_above`` deg) and the default is below
    ``fraction`` of that."""
    rmses = default_and(drive, name, overrides, **config)
    assert rmses[name] > without_above, rmses
    assert rmses["default"] < fraction * rmses[name], rmses
