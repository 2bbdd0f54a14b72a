"""jaxmodel/wheel_step.py: a step of the wheel heading told from the compass's own errors by how the disagreement
depends on the heading and on |B|."""

import sys
from pathlib import Path

import numpy as np
import pytest

import jax.numpy as jnp

from identification import scenarios as sc
from jaxmodel import wheel_step as ws
from matrix_drives import default_rmse_after_first_minute

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_outside_matrix as outside_matrix  # noqa: E402

B = 20.0  # µT


def _feed(headings_deg, nu_deg, field=None, episode=True):
    """Samples 1 m apart at EH = ``headings_deg`` with the disagreement ``nu_deg`` (a function of the heading, deg)
    and |B| = ``field`` (a function of the heading, µT; default B); returns (final state, first step found (deg) or
    None, whether a step was ever suspected)."""
    field = field or (lambda psi: B)
    state, step, suspected = ws.init_wheel_step_state(), None, False
    for psi in np.radians(np.asarray(headings_deg, float)):
        state, found, suspect = ws.update(state, jnp.asarray(np.radians(nu_deg(psi))), jnp.asarray(psi),
                                          jnp.asarray(field(psi)), jnp.asarray(B), jnp.asarray(1.0),
                                          jnp.asarray(True), jnp.asarray(episode))
        suspected |= bool(suspect)
        if step is None and float(found) != 0.0:
            step = float(np.degrees(found))
    return state, step, suspected


# An urban drive: 60 m north, 60 m east, 60 m south (bins 90 deg apart, never turning while the samples are summed).
GRID = np.concatenate([np.full(60, 10.0), np.full(60, 100.0), np.full(60, 190.0)])


@pytest.mark.parametrize("step_deg", [-16.0, 6.0, 50.0])
def test_one_angle_at_every_heading_is_a_step_of_the_wheels(step_deg):
    _, step, suspected = _feed(GRID, lambda psi: step_deg)
    assert step == pytest.approx(step_deg, abs=1e-9) and suspected


def test_one_heading_only_is_suspected_not_taken():
    """A straight road: a step of the wheels and a hard iron at its peak read alike; the compass-shift learner waits,
    F-DELTA does not move."""
    _, step, suspected = _feed(np.full(300, 10.0), lambda psi: 12.0)
    assert step is None and suspected


def test_neighbouring_bins_are_not_spread_enough():
    _, step, _ = _feed(np.concatenate([np.full(60, 40.0), np.full(60, 50.0)]), lambda psi: 12.0)
    assert step is None


@pytest.mark.parametrize("amplitude_deg", [8.0, 16.0])
def test_a_shifted_hard_iron_is_no_step(amplitude_deg):
    """A hard iron h fixed in the vehicle: the angle error A sin(psi - phi) and |B| = |B_E u + h| both follow the
    heading (peak in the middle bin of the grid)."""
    h = B * np.tan(np.radians(amplitude_deg))
    phi = np.radians(-190.0)  # in the vehicle's frame, where the earth's field reads B exp(-i psi)

    def angle(psi):  # the compass heading's error, -arg(B exp(-i psi) + h exp(i phi)) - psi
        return -np.degrees(np.angle(B + h * np.exp(1j * (phi + psi))))

    def magnitude(psi):
        return abs(B + h * np.exp(1j * (phi + psi)))

    assert abs(angle(np.radians(100.0))) == pytest.approx(amplitude_deg, abs=0.01)  # the peak, in the middle bin
    _, step, _ = _feed(GRID, angle, magnitude)
    assert step is None


def test_an_anomaly_that_moves_the_field_is_no_step():
    """|B| off by 10 % on most of the samples: an anomaly, however steadily it turns the compass."""
    _, step, suspected = _feed(GRID, lambda psi: 20.0, lambda psi: 1.1 * B if psi < np.radians(150.0) else B)
    assert step is None and not suspected


def test_small_disagreements_are_the_filters_to_weigh():
    _, step, suspected = _feed(GRID, lambda psi: 3.0)
    assert step is None and not suspected


def test_the_sums_restart_outside_an_episode():
    state, _, _ = _feed(GRID[:100], lambda psi: 12.0)
    assert float(np.sum(state.fields().w)) > 0.0
    state, _, _ = ws.update(state, jnp.asarray(0.2), jnp.asarray(0.0), jnp.asarray(B), jnp.asarray(B),
                            jnp.asarray(1.0), jnp.asarray(True), jnp.asarray(False))
    assert float(np.sum(np.abs(state.vector))) == 0.0


@pytest.mark.slow
def test_a_chatter_of_spurious_pulses_is_taken_out_once_the_headings_tell(traced_constants):
    """bench/bench_outside_matrix.py's pulse_chatter (1 pulse per sample on the left wheel for 2 s: each sample within
    the guard's tolerance, 20 pulses in all, ~16 deg of wheel heading for good) on urban/baseline/107, a judge seed
    of that row (the form of wheel_step.py was chosen on seeds 101 and 104).  Measured (stop 64): the default 6.01 deg
    RMSE after the first minute without the step (the compass clean within 2 deg: 1.43 deg alone), 2.91 deg with it;
    the clean drive 0.34 deg either way.  Since stop 70 3.94 deg without the step: the steady filter is no longer
    hardened against a compass that the rate filter follows (``rate_significance.steady_lags``)."""
    drive = sc.make_drive("urban", "baseline", 107)
    clean = default_rmse_after_first_minute(drive)
    outside_matrix.DISTURBANCES["pulse_chatter"](drive)
    with_step = default_rmse_after_first_minute(drive)
    with traced_constants((ws, "STEP_MIN_M", 1e12)):
        without = default_rmse_after_first_minute(drive)
    assert clean < 0.5 and with_step < 3.5 and without > 1.25 * with_step, (clean, with_step, without)
