"""heading_reliability is the output mode's own (SPEC §8): the Kalman filter's from its covariance
(jaxmodel/kalman.py: bound), the single-sensor modes' from the fused heading's bound plus their distance from it."""

import math

import numpy as np
import pytest

import jaxmodel as jm
from identification import scenarios as sc
from jaxmodel.heading_filter import reliability as reliability_of_bound
from matrix_drives import heading_error_deg, run_drive


def _outputs(drive, mode):
    """|heading error| (deg), reliability, bound (rad) of ``mode`` on ``drive``, per sample."""
    out = run_drive(drive, mode=mode)
    return np.abs(heading_error_deg(out, drive)), np.asarray(out.heading_reliability), np.asarray(out.heading_bound)


@pytest.mark.slow
def test_each_mode_says_how_far_its_own_heading_can_be_trusted():
    """urban/mismatch_1.5/102 (nominal dpp on both wheels): the wheel heading runs 100+ deg off before the
    calibration has found the mismatch, while the fused heading stays within a few degrees.  Before stop 48 every
    mode printed the fused heading's reliability (the odometer mode's heading 150 deg off at 0.4-0.6); now the
    odometer mode's bound covers its error wherever the fused bound covers the fused error, and the compass mode's
    likewise."""
    drive = sc.make_drive("urban", "mismatch_1.5", 102, duration_s=450.0)
    err_f, rel_f, bound_f = _outputs(drive, "complementary")
    covered = np.degrees(bound_f) + 2.0 >= err_f  # where the fused heading's bound is honest (2 deg of slack)
    for mode in ("odometer", "compass"):
        err, rel, bound = _outputs(drive, mode)
        assert np.all(np.degrees(bound[covered]) + 2.0 >= err[covered]), mode
        assert np.all(rel <= 1.0) and np.all(rel > 0.0)
    err_o, rel_o, _ = _outputs(drive, "odometer")
    far = err_o > 60.0
    assert far.sum() > 100, far.sum()
    p = jm.make_params(drive.params)
    assert np.all(rel_o[far] < float(reliability_of_bound(p, math.radians(50.0))))
    assert np.median(rel_f[far]) > float(reliability_of_bound(p, math.radians(10.0)))  # the fused heading was fine
