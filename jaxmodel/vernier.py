"""The two-sided re-estimate of a rounded burst removal (the odometer guard's vernier).

The guard (jaxmodel/plausibility.py) removes a burst of spurious pulses from the wheel at fault as a whole number,
predicted from the dD rate before the burst.  One sample's dD cannot tell its own quantization: on a straight road the
per-sample dD alternates between whole numbers of pulses, and the rounding then leaves one spurious pulse, 0.4-1.1 deg
of wheel heading for good on the matrix's vehicles.  The cumulative dD D(k) of the samples about the removal can: each
wheel's count is its travel less a fraction of a pulse, so about the true line of D (a steady turn rate) D stays
within a band two pulses wide, and a pulse left over widens that band on one side of the removal by a pulse.

The re-estimate keeps the kept dD of the last VERNIER_WINDOW samples (VERNIER_BEFORE before the removal and
VERNIER_SAMPLES from it on) and, once they are seen, asks which residual step m of -1, 0 or +1 pulse of the wheel at
fault leaves D - m H (H = 1 from the removal on) in the narrowest band about a line: the minimax (Chebyshev) fit, whose
width is that of the points' thinnest enclosing strip, at the slope of one of the pairs of points.  Quantization is
bounded, not Gaussian: least squares of a line and a step over the same samples found the exact burst on 76 of the 99
bursts of seeds 101-111, the narrowest band on 89 (stop 83, offline).  The pulse is taken off when its band is
narrower than the uncorrected one by VERNIER_MARGIN pulses.  The samples are taken as evenly spaced (the index k).

One estimate is pending at a time.  A rounded removal while another is pending replaces it, and the one replaced
waits in a second slot (the shadow): a spike's first sample is a rounded removal too (3000 pulses is no counter
modulus), and when the spike returns (an exact removal undoing it) its own estimate is cancelled and the burst's
before it is pending again.  A counter modulus removed (a wrap at another modulus) leaves its sample's dD right and
cancels nothing.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .packed import computed_once, value_once
from .seldom import where_needed

VERNIER_BEFORE = 8
"""Kept samples before a rounded removal that its re-estimate fits."""
VERNIER_SAMPLES = 8
"""Kept samples from a rounded removal on (itself included) before it is estimated again from both sides."""
VERNIER_WINDOW = VERNIER_BEFORE + VERNIER_SAMPLES
VERNIER_MARGIN = 0.15
"""Pulses by which the corrected band must be narrower than the uncorrected one for the pulse to be taken off."""
VERNIER_MAX_BAND = 2.0
"""Pulses: the widest band the counts' quantization leaves about a line of D (each wheel's count within one pulse of
its travel: dD within (-1, 1) pulse of its true line).  A narrowest band wider than this is no line: the turn rate
changed within the window (a bend begins), and a step of a pulse cannot be told from it: nothing is taken off.  Of the
99 bursts of seeds 101-111 it changes one decision: a removal that was right, at a bend's onset (narrowest band 6
pulses), which lost a pulse without it (stop 85)."""

FIELDS = (("vernier_wheel", "vernier_after", "vernier_shadow_wheel", "vernier_shadow_after")
          + tuple(f"vernier_dD_{i:02d}" for i in range(VERNIER_WINDOW)))
"""The guard state's fields the vernier owns, in order: the wheel a removal is pending on (+1 left, -1 right, 0 none),
the kept samples seen from it on, the same two of the estimate it replaced (the shadow), and the kept dD (m) of the
last VERNIER_WINDOW samples, oldest first."""
_RING = 4
"""Where the ring of kept dD begins in FIELDS."""

_K = np.arange(VERNIER_WINDOW, dtype=float)
_STEP = (_K >= VERNIER_BEFORE).astype(float)
_CUMULATIVE = np.tril(np.ones((VERNIER_WINDOW, VERNIER_WINDOW)))
"""D = dD @ _CUMULATIVE.T (a constant matrix: the native FMU's lowering has no cumsum)."""
PAIR_SEPARATION = 6
"""The minimax line's slope is that of an edge of the points' convex hull, some pair of them; on the cumulative dD of a
road (near a line, within the band of quantization) the hull's edges are long, and the pairs at least this many samples
apart find the same width as all 120 (3000 simulated windows of quantized turns: identical; 8 apart: 5 % thinner
bands missed) at less than half the cost."""
_I, _J = np.triu_indices(VERNIER_WINDOW, 1)
_I, _J = _I[_J - _I >= PAIR_SEPARATION], _J[_J - _I >= PAIR_SEPARATION]
_PAIR_SLOPES = np.zeros((VERNIER_WINDOW, _I.size))
_PAIR_SLOPES[_J, np.arange(_I.size)] = 1.0 / (_J - _I)
_PAIR_SLOPES[_I, np.arange(_I.size)] = -1.0 / (_J - _I)
"""D @ _PAIR_SLOPES: the slopes of those pairs of points."""
_CANDIDATES = np.array([-1.0, 0.0, 1.0])


def _lifted(constant, batch):
    """A numpy constant with ``batch`` leading axes of one (the suite runs with strict rank promotion)."""
    return jnp.asarray(constant).reshape((1,) * batch + constant.shape)


def band_widths(D, step):
    """The width (m) of the narrowest band about a line of D - m step H, for m in (-1, 0, 1).

    D: (..., VERNIER_WINDOW) cumulative dD (m); step: (...,) one pulse of dD of the wheel at fault (m, signed).
    Returns (..., 3)."""
    batch = D.ndim - 1
    shifted = D[..., None, :] - step[..., None, None] * _lifted(_CANDIDATES[:, None] * _STEP, batch)  # (..., 3, W)
    slopes = shifted @ _PAIR_SLOPES  # (..., 3, pairs)
    # Reduced over the samples (a major axis): the pairs, the minor one, vectorize (15 % faster than the other way).
    residual = shifted[..., :, None] - _lifted(_K[:, None], batch + 1) * slopes[..., None, :]  # (..., 3, W, pairs)
    return jnp.min(jnp.max(residual, axis=-2) - jnp.min(residual, axis=-2), axis=-1)


def leftover_pulse(widths, step):
    """The residual step (pulses, -1, 0 or +1) whose band is the narrowest, and whether it is clear: its band is
    narrower than the uncorrected one by VERNIER_MARGIN pulses, and no wider than VERNIER_MAX_BAND.

    widths: (..., 3) ``band_widths``; step: (...,) one pulse of dD (m, signed).  Returns ((...,), (...,) bool)."""
    narrowest = jnp.min(widths, axis=-1)
    missed = jnp.max(jnp.where(widths == narrowest[..., None], _lifted(_CANDIDATES, narrowest.ndim), -jnp.inf), axis=-1)
    clear = ((missed != 0.0) & (widths[..., 1] - narrowest > VERNIER_MARGIN * jnp.abs(step))
             & (narrowest <= VERNIER_MAX_BAND * jnp.abs(step)))
    return missed, clear


def vernier(fields, d_left, d_right, usable, start, cancel, wheel, dpp_left, dpp_right):
    """One sample of the re-estimate.

    fields: (..., len(FIELDS)) this module's part of the guard state; d_left, d_right: the sample's kept increments
    (m, after the guard's removal); usable: kept and in order in time; start: this sample made a rounded removal
    from ``wheel`` (+1 left, -1 right); cancel: the pending estimate is void (a returning spike undid the removal
    that began it, or a stuck wheel's turn was substituted: no step to see); dpp_left, dpp_right: metres per pulse.
    Returns (d_left, d_right, the new fields, whether a pulse was taken off).
    """
    ring = fields[..., _RING:]
    ring = jnp.where(usable[..., None], jnp.concatenate([ring[..., 1:], (d_left - d_right)[..., None]], axis=-1), ring)
    begun = start & usable
    # A cancelled estimate gives way to the one it had replaced (the shadow), counted on from this sample.
    shadow_wheel, shadow_after = fields[..., 2], fields[..., 3]
    restored = cancel & (shadow_wheel != 0.0)
    ring = _bridged(ring, restored, fields[..., 1])
    pending_wheel = jnp.where(cancel, jnp.where(restored, shadow_wheel, 0.0), fields[..., 0])
    after = jnp.where(cancel, jnp.where(restored, shadow_after, 0.0), fields[..., 1])
    pending = computed_once((pending_wheel != 0.0) & usable)
    wheel_now = jnp.where(begun, wheel, pending_wheel)
    counted = jnp.where(pending, after + 1.0, after)
    after = jnp.where(begun, 1.0, counted)
    due = computed_once(pending & ~begun & (after >= VERNIER_SAMPLES))
    left = wheel_now > 0.0
    # A value read by every element of the bands: computed once (packed.value_once).
    step = value_once(jnp.where(left, dpp_left, -dpp_right))  # one pulse of the wheel at fault in dD
    # Read on the due sample only: computed on the samples where some drive of the batch is due (jaxmodel/seldom.py).
    widths = where_needed(due, lambda dD, pulse: band_widths(dD @ _CUMULATIVE.T, pulse), ring, step)
    missed, clear = leftover_pulse(widths, step)
    fired = due & clear
    taken = jnp.where(fired, missed, 0.0)
    d_left = d_left - jnp.where(left, taken * dpp_left, 0.0)
    d_right = d_right - jnp.where(left, 0.0, taken * dpp_right)
    ring = jnp.concatenate([ring[..., :-1], ring[..., -1:] - (taken * step)[..., None]], axis=-1)
    wheel_kept = jnp.where(due, 0.0, wheel_now)
    after = jnp.where(due, 0.0, after)
    shadow_wheel, shadow_after = _next_shadow(shadow_wheel, shadow_after, restored, begun, pending_wheel, counted,
                                              usable, due)
    return d_left, d_right, jnp.concatenate(
        [wheel_kept[..., None], after[..., None], shadow_wheel[..., None], shadow_after[..., None], ring],
        axis=-1), fired


def _bridged(ring, restored, cancelled_after):
    """The ring with the samples of a returned spike bridged: from the spike's first sample (``cancelled_after``
    samples before this one, its estimate's count) to its return, the kept dD all take their mean.

    The spike's rounded removal can miss by a pulse, and its return undoes exactly what was removed: D is right
    again from the return on, but off by that pulse in between, which would widen every band of the burst's
    estimate.  Bridged, D runs on the chord between two of its points, inside every band that holds them: the
    widths are those of the window without the spike's samples."""
    span = jnp.where(restored, cancelled_after + 1.0, 0.0)  # the spike's samples and its return
    inside = _lifted(_K, ring.ndim - 1) >= VERNIER_WINDOW - span[..., None]
    mean = jnp.sum(jnp.where(inside, ring, 0.0), axis=-1) / jnp.maximum(span, 1.0)
    return jnp.where(inside, mean[..., None], ring)


def _next_shadow(shadow_wheel, shadow_after, restored, begun, pending_wheel, counted, usable, due):
    """The shadow slot after the sample.  A rounded removal's estimate replaces a pending one, which moves here with
    this sample counted; a shadow counts every usable sample (its window moves on with the ring) and is dropped once
    restored, once the estimate that replaced it is due (that window holds a second removal) and once its own
    window has passed (a restored shadow is due on VERNIER_SAMPLES at the latest)."""
    shadow_after = jnp.where((shadow_wheel != 0.0) & usable, shadow_after + 1.0, shadow_after)
    gone = restored | due | (shadow_after >= VERNIER_SAMPLES)
    replaced = begun & (pending_wheel != 0.0)
    return (jnp.where(replaced, pending_wheel, jnp.where(gone, 0.0, shadow_wheel)),
            jnp.where(replaced, counted, jnp.where(gone, 0.0, shadow_after)))
