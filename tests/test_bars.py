"""Issue 2 bar: on 15-minute simulated drives with magnetic anomalies, driven with the true
parameters, the complementary heading RMSE after the first minute is <= 1.5 deg urban and
<= 1.0 deg mixed and motorway, and at most half the compass-only RMSE (docs/tuning.md).

The bar was set for the seed's filter (``Config(robust=False)``), which still meets it on the
project's own simulator.  The default (robust) filter is judged on issue 10's scenario matrix
instead (tests/test_scenarios.py, bench/bench_scenarios.py): it trades about 0.5 deg on these
clean drives for never failing by tens of degrees on a tyre mismatch or a pulse burst."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from identification.drive_log import drive_from_columns
from identification.simulate import simulate

LIMIT_DEG = {"urban": 1.5, "mixed": 1.0, "highway": 1.0}
_run = jax.jit(lambda p, i, mode: jm.run(p, i, jm.Config(mode=mode, robust=False)).heading, static_argnames="mode")


def rmse_after_first_minute(heading, truth, t):
    err = np.angle(np.exp(1j * (np.asarray(heading) - truth)))[t - t[0] >= 60.0]
    return float(np.rad2deg(np.sqrt(np.mean(err**2))))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("scenario", ["urban", "mixed", "highway"])
def test_complementary_heading_bar(scenario, seed):
    columns, truth = simulate(scenario, 900.0, seed)
    drive = drive_from_columns(columns, source=f"{scenario}-{seed}")
    params = jm.make_params(truth["params"])
    inputs = jax.tree_util.tree_map(jnp.asarray, drive.inputs)
    t = np.asarray(drive.inputs.time_s)
    ref = np.asarray(truth["heading_rad"])
    compass = rmse_after_first_minute(_run(params, inputs, "compass"), ref, t)
    complementary = rmse_after_first_minute(_run(params, inputs, "complementary"), ref, t)
    assert complementary <= LIMIT_DEG[scenario], (compass, complementary)
    assert complementary <= 0.5 * compass, (compass, complementary)
