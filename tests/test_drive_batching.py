"""Batches of drives (identification.drive_log.stack_drives, stack_reference): padded with a standing vehicle, one
compiled shape whose rows equal single runs, and the padding rule shared with fleet_fit.pad_batch."""

import numpy as np
import pytest

import jaxmodel
from identification import DriveLogError
from identification.drive_log import drive_from_columns, stack_drives, stack_reference

from drives import assert_same, synthetic_columns


def test_stack_drives_pads_with_a_standing_vehicle():
    d1 = drive_from_columns(synthetic_columns(n=30, seed=1), source="one")
    d2 = drive_from_columns(synthetic_columns(n=45, seed=2), source="two")
    inputs, mask = stack_drives([d1, d2])
    assert isinstance(inputs, jaxmodel.Inputs)
    for k in jaxmodel.Inputs._fields:
        assert getattr(inputs, k).shape == (2, 45), k
    assert mask.shape == (2, 45) and mask.dtype == np.float64
    assert mask[0].tolist() == [1.0] * 30 + [0.0] * 15 and np.all(mask[1] == 1.0)
    t = inputs.time_s[0]
    last_step = d1.inputs.time_s[-1] - d1.inputs.time_s[-2]
    assert np.allclose(np.diff(t[29:]), last_step) and np.all(np.diff(t) > 0)
    assert np.all(inputs.left_pulses[0, 30:] == d1.inputs.left_pulses[-1])
    assert np.all(inputs.right_pulses[0, 30:] == d1.inputs.right_pulses[-1])
    assert np.all(inputs.compass_x[0, 30:] == d1.inputs.compass_x[-1])
    assert np.all(inputs.compass_y[0, 30:] == d1.inputs.compass_y[-1])
    assert np.all(inputs.map_valid[0, 30:] == 0.0) and np.all(inputs.fix_valid[0, 30:] == 0.0)
    for k in jaxmodel.Inputs._fields:
        assert_same(getattr(inputs, k)[1], getattr(d2.inputs, k), k)
        assert_same(getattr(inputs, k)[0, :30], getattr(d1.inputs, k), k)

    ref, ref_mask = stack_reference([d1, d2])
    assert ref.shape == (2, 45) and np.all(np.isfinite(ref))
    assert np.array_equal(ref_mask, mask)


def test_padding_a_stacked_batch_equals_stacking_to_that_length():
    """fleet_fit.pad_batch (arrays) and stack_drives (drives) pad by the one rule of drive_log.pad_inputs."""
    from identification.fleet_fit import pad_batch

    drives = [drive_from_columns(synthetic_columns(n=n, seed=n), source=str(n)) for n in (30, 45)]
    inputs, mask = stack_drives(drives)
    ref = np.ones_like(mask)
    padded, padded_mask, padded_ref = pad_batch(inputs, mask, ref, 64)
    direct, direct_mask = stack_drives(drives, length=64)
    for k in jaxmodel.Inputs._fields:
        assert_same(getattr(padded, k), getattr(direct, k), k)
    assert np.array_equal(padded_mask, direct_mask)
    assert padded_ref.shape == (2, 64) and np.all(padded_ref[:, 45:] == 0.0)
    assert pad_batch(inputs, mask, ref, 45)[0] is inputs  # nothing to pad


def test_stack_drives_single_sample_and_missing_reference():
    cols = synthetic_columns(n=1)
    d1 = drive_from_columns(cols)
    d2 = drive_from_columns(synthetic_columns(n=3))
    inputs, mask = stack_drives([d1, d2])
    assert np.all(np.diff(inputs.time_s[0]) > 0) and mask[0].tolist() == [1.0, 0.0, 0.0]
    cols = synthetic_columns(n=3)
    cols["ref_heading_deg"][1] = np.nan
    _, ref_mask = stack_reference([drive_from_columns(cols)])
    assert ref_mask.tolist() == [[1.0, 0.0, 1.0]]
    del cols["ref_heading_deg"]
    with pytest.raises(DriveLogError):
        stack_reference([drive_from_columns(cols, source="noref")])
    with pytest.raises(ValueError):
        stack_drives([])


def test_stacked_batch_matches_single_runs():
    params = jaxmodel.make_params(sensor_axle="rear")
    drives = [drive_from_columns(synthetic_columns(n=n, seed=n)) for n in (40, 64)]
    inputs, mask = stack_drives(drives)
    batch = jaxmodel.run_batch(params, inputs)
    assert drives[1].n_samples == inputs.time_s.shape[1]
    for b, d in enumerate(drives):
        # one compiled shape: the scan is causal, so the padded row's real part is the drive's run
        padded_row = jaxmodel.Inputs(*(np.asarray(v)[b] for v in inputs))
        single = jaxmodel.run(params, padded_row)
        n = d.n_samples
        for k in ("heading", "x", "y", "wheel_heading"):
            np.testing.assert_allclose(np.asarray(getattr(batch, k))[b, :n], np.asarray(getattr(single, k))[:n],
                                       rtol=0, atol=1e-12, err_msg=k)
        # padding is a standing vehicle: the position does not move
        x, y = np.asarray(batch.x)[b], np.asarray(batch.y)[b]
        assert np.all(x[n:] == x[n - 1]) and np.all(y[n:] == y[n - 1])
    assert np.asarray(batch.heading).dtype == np.float64
