"""The wheel heading between pulses: the counts' quantization taken out of the heading output.

H_W (US 4,734,863 FIG. 8B) turns by whole pulses: each wheel's count is within one pulse of its travel, so
dD, and with it H_W, carries the difference of two quantization errors, each uniform over a pulse: a standard
deviation of 1/sqrt(6) pulse of dD, dpp / T of heading per pulse (0.8 deg on the scenario matrix's vehicles, 2.5 deg
with 7-cm pulses).  It does not accumulate (the counts are cumulative), but it flickers: on a straight road dD
steps by one pulse and back from one sample to the next as the two wheels' pulses pass their edges at different
times, and EH = H_W + F-DELTA shows every step.  Measured on the matrix's baseline drives of seeds 101 and 104 (stop
37, docs/tuning.md): the default's error faster than 0.5 s was 0.26-0.32 deg RMS of its 0.40-0.53 deg.

The seeds are silent here (their EH is H_W + F-DELTA sample by sample).  A constant-turn-rate Kalman filter runs on
H_W: state (epsilon, omega) = (its estimate of the heading less H_W, rad; the turn rate, rad/s), H_W measured with
the quantization's variance R = (dpp / T)^2 / 6, the turn rate a random walk of DEQUANT_RATE_PSD rad^2/s^3.
Standing still it does not turn; across a time step beyond DEQUANT_HORIZON_S (a logger that stopped) it starts
again.  epsilon is kept within DEQUANT_MAX_PULSES pulses of heading (dpp / T each): it takes out quantization,
never a turn the wheels counted.  The heading output of the robust modes that turn with the wheels
(complementary, odometer, kalman) is the mode's heading + epsilon; H_W, F-DELTA and the filters are unchanged.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .packed import computed_once, packed_state

DEQUANT_RATE_PSD = 1e-3
"""Turn-rate random walk (rad^2/s^3): a yaw acceleration of ~0.03 rad/s^2 per square-root second.  Chosen on the
matrix's tuning seeds 101-103 (3e-4 / 1e-3 / 3e-3 / 1e-2: geometric mean 0.852 / 0.850 / 0.855 / 0.864 deg, 0.901
without the filter); held-out seeds 104-106 0.833 -> 0.792 deg."""
DEQUANT_MAX_PULSES = 2.0
"""|epsilon| at most this many pulses of wheel heading (dpp / T each)."""
DEQUANT_HORIZON_S = 2.0
"""A time step longer than this (s) restarts the filter: its turn rate says nothing across it."""
DEQUANT_RATE_SIGMA0 = 0.1
"""Turn rate's standard deviation when the filter starts (rad/s)."""
QUANTIZATION_SIGMA = 6.0 ** -0.5
"""Standard deviation of the difference of two counts' quantizations, each uniform over one pulse (pulses)."""


class DequantFields(NamedTuple):
    """epsilon (rad): the heading estimate less H_W; omega (rad/s): the turn rate; p00, p01, p11 their covariance."""

    epsilon: jnp.ndarray
    omega: jnp.ndarray
    p00: jnp.ndarray
    p01: jnp.ndarray
    p11: jnp.ndarray


DequantState = packed_state(DequantFields, "DequantState", "State of the wheel heading's dequantization filter.")


def _started(quantum_sigma):
    z = jnp.zeros_like(quantum_sigma)
    return DequantFields(z, z, quantum_sigma ** 2, z, z + DEQUANT_RATE_SIGMA0 ** 2)


def init_dequant_state() -> DequantState:
    return DequantState.pack(_started(jnp.zeros((), jnp.float64)))


def pulse_heading(dpp, track):
    """Wheel heading of one pulse of dD (rad): dpp / T."""
    return dpp / track


def update(ds, alpha, dt, moving, pulse, restart, dt_moved=None):
    """One sample: returns (new state, epsilon (rad), to add to the mode's heading).

    alpha: this sample's wheel turn (rad, FIG. 8B's increment of H_W); dt: its time step (s, 0 when unusable);
    moving: the wheels travelled (bool); pulse: the heading of one pulse of dD (rad, ``pulse_heading``); restart:
    H_W was (re)started this sample or has not started (bool); dt_moved: the time (s) a moving sample's counts
    cover (longer than dt after held counters, ``odometer.COUNTS_HOLD_MAX_S``; dt if None).
    """
    f = ds.fields()
    quantum_sigma = QUANTIZATION_SIGMA * pulse
    gap = dt > DEQUANT_HORIZON_S
    dt_turn = jnp.where(moving & ~gap, dt if dt_moved is None else dt_moved, 0.0)
    # Predict: the estimate turns at omega, H_W by alpha.
    e = f.epsilon + f.omega * dt_turn - alpha
    p00 = f.p00 + dt_turn * (2.0 * f.p01 + dt_turn * f.p11)
    p01 = f.p01 + dt_turn * f.p11
    p11 = f.p11 + DEQUANT_RATE_PSD * jnp.where(gap, 0.0, dt)
    # Measure H_W (the innovation is -e) with the quantization's variance.
    inv = 1.0 / (p00 + quantum_sigma ** 2)
    k0, k1 = p00 * inv, p01 * inv
    omega = f.omega - k1 * e
    e = e * (1.0 - k0)
    p11 = p11 - k1 * p01
    p00, p01 = (1.0 - k0) * p00, (1.0 - k0) * p01
    limit = DEQUANT_MAX_PULSES * pulse
    e = jnp.clip(e, -limit, limit)
    new = DequantFields(e, omega, p00, p01, p11)
    again = computed_once(restart | gap | ~jnp.isfinite(e + omega))
    out = DequantState.pack(DequantFields(*[jnp.where(again, s, n) for s, n in zip(_started(quantum_sigma), new)]))
    return out, out.epsilon
