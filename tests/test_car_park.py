"""The default mode in a car park (issue 10, stop 62): long disturbances of a slow drive that turns all the time.

Diagnosis seeds of the matrix's parking/long_disturbance drives (never the evaluation seeds 201-203): the field of a
car park turned the compass 40-80 deg, wandering, for minutes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from identification import scenarios as sc
from identification.drive_log import drive_from_columns
from jaxmodel import model as jmodel
from jaxmodel import offset_filter as of

from matrix_drives import default_rmse_after_first_minute, run_drive


def test_a_turn_ages_the_start_anchor_as_anchor_turn_m_metres_a_radian():
    """``young`` counts the metres of absolute headings and ANCHOR_TURN_M for each radian the wheels turned with a
    compass the steady filter accepted (a clean drive: nearly all of them): the first five minutes of a parking drive
    (~350 m) age it past filter_reacquire_m."""
    drive = sc.make_drive("parking", "baseline", 101, duration_s=300.0)
    params = jm.make_params(dict(drive.params))
    inputs = jax.tree_util.tree_map(jnp.asarray, drive_from_columns(drive.columns, source="car park").inputs)
    state, out = jmodel.run_from(params, jmodel.init_state(params), inputs, jm.Config())
    driven = float(out.distance[-1])
    turned = float(np.sum(np.abs(np.diff(np.unwrap(np.asarray(out.wheel_heading))))))
    assert driven < 500.0 and turned > 20.0  # a car park: little distance, many turns
    aged = float(state.distance_filtered)
    assert aged == pytest.approx(driven + of.ANCHOR_TURN_M * turned, rel=0.1)
    assert bool(of.young(params, driven)) and not bool(of.young(params, aged))


@pytest.mark.slow
@pytest.mark.parametrize("seed, before", [(391, 21.1), (352, 43.2)])
def test_a_car_parks_field_does_not_restart_an_anchor_that_turned(seed, before):
    """Young by distance all drive (1.3 km in 15 minutes), the anchor was restarted as lost by a car park's field 40-80
    deg off that wandered by 15 deg (a young anchor takes a compass as steady as that): ``before`` deg RMSE after the
    first minute.  Aged by its turns, it is lost only to a compass as steady as a clean one."""
    drive = sc.make_drive("parking", "long_disturbance", seed)
    assert default_rmse_after_first_minute(drive) < 2.0 < before


@pytest.mark.slow
def test_a_lost_restart_keeps_the_tyres_rate():
    """parking/long_disturbance/314: the rate filter restarted as lost from a car park's field; restarted with it, its
    rate learned 8 mrad/m from the field settling and the calibration captured a 1.2 % tyre mismatch the tyres do not
    have (dpp_ratio 0.9876, 7.31 deg RMSE).  The lost restart keeps the rate."""
    drive = sc.make_drive("parking", "long_disturbance", 314)
    out = run_drive(drive)
    assert np.max(np.abs(np.asarray(out.dpp_ratio) - 1.0)) < 2e-3
    assert default_rmse_after_first_minute(drive) < 4.0
