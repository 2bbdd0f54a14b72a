"""jaxmodel/compass_shift.py: a shifted hard iron learned from the wheels' heading while the compass is rejected."""

import numpy as np
import pytest

import jax.numpy as jnp

from jaxmodel import compass_shift as cs

B = 20.0  # µT


def _learn(offset, headings_deg, field_turn_deg=0.0, rotation_deg=0.0):
    """Feed samples 1 m apart at the true headings (EH exact) with the compass offset by ``offset`` (x forward,
    y left; µT) and the field turned by ``field_turn_deg`` (an anomaly fixed in the world); returns the state."""
    state = cs.init_shift_state()
    rot = np.radians(rotation_deg)
    for psi in np.radians(np.asarray(headings_deg, float)):
        a = psi + np.radians(field_turn_deg) + rot
        # As the model does: the components with the change learned so far taken out.
        x, y = B * np.cos(a) + offset[0] - float(state.ox), B * np.sin(a) + offset[1] - float(state.oy)
        h_c = np.arctan2(y, x) - rot
        state = cs.update(state, jnp.asarray(x), jnp.asarray(y), jnp.asarray(h_c), jnp.asarray(psi), jnp.asarray(B),
                          jnp.asarray(1.0), jnp.asarray(True), jnp.asarray(rot))
    return state


SWEEP = np.linspace(0.0, 120.0, 400)  # 400 m turning through 120 deg


@pytest.mark.parametrize("offset", [(2.0, 4.0), (-3.0, -3.0), (0.5, -5.0)])
def test_a_shift_fixed_in_the_vehicle_is_learned_while_turning(offset):
    state = _learn(offset, SWEEP)
    assert float(state.ox) == pytest.approx(offset[0], abs=0.15)
    assert float(state.oy) == pytest.approx(offset[1], abs=0.15)


def test_the_shift_is_learned_in_the_compass_frame_of_a_rotated_mounting():
    state = _learn((4.0, 2.0), SWEEP, rotation_deg=90.0)
    assert float(state.ox) == pytest.approx(4.0, abs=0.15) and float(state.oy) == pytest.approx(2.0, abs=0.15)
    # On a compass mounted turned by 90 deg the vehicle's forward axis is the compass's y: a grade's error.
    assert float(_learn((0.0, 4.0), SWEEP, rotation_deg=90.0).oy) == 0.0


@pytest.mark.parametrize("case, offset, headings, turn", [
    ("straight on: no spread of headings", (2.0, 4.0), np.full(400, 30.0), 0.0),
    ("too little of it", (2.0, 4.0), SWEEP[:120], 0.0),
    ("along the forward axis: a grade's dip error", (4.0, 0.5), SWEEP, 0.0),
    ("too small to matter", (0.3, 1.2), SWEEP, 0.0),
    ("a field turned in the world: the residual turns with the heading", (0.0, 0.0), np.linspace(0, 180, 400), 15.0),
])
def test_nothing_else_moves_the_offsets(case, offset, headings, turn):
    state = _learn(offset, headings, field_turn_deg=turn)
    assert float(state.ox) == 0.0 and float(state.oy) == 0.0, case


def test_rejected_samples_only():
    state = cs.init_shift_state()
    for psi in np.radians(SWEEP):
        state = cs.update(state, jnp.asarray(B * np.cos(psi) + 2.0), jnp.asarray(B * np.sin(psi) + 4.0),
                          jnp.asarray(psi), jnp.asarray(psi), jnp.asarray(B), jnp.asarray(1.0), jnp.asarray(False))
    assert float(state.w) == 0.0 and float(state.ox) == 0.0
