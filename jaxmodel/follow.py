"""The steady F-DELTA drawn to the rate filter (``offset_filter``'s two filters, one heading).

The rate filter follows a drifting wheel heading (a tyre mismatch before the calibration has caught it); the steady
filter, without a rate, gives the heading.  ``follow`` shows the rate filter while its rate is significant and takes
its state during the follow hold after a confirmed drift, which ``offset_filter.restart_hold`` and
``offset_filter.count_since_large_drift`` count (docs/tuning.md, stops 30 and 47).  ``restart_together`` couples the
two filters' restarts, since both watch one compass (docs/tuning.md, stop 50).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import calibration as _cal
from . import offset_filter as _of
from . import rate_significance as _rate
from .angles import wrap
from .packed import computed_once
from .params import deg


CALIBRATED_SHOW_FRACTION = 0.1
"""filter_follow_show_rate is this much smaller once the calibration has moved the ratio (``follow``)."""


CALIBRATED_TURN_FRACTION = 0.5
"""The rate filter's turn noise moves this fraction of the way from filter_turn_sigma to filter_steady_turn_sigma once
the calibration has moved the ratio (``calibrated_rate_params``)."""


def calibrated_rate_params(params, calibrated):
    """Constants of the rate filter once the calibration has moved the ratio (``calibrated`` in [0, 1],
    ``calibration.corrected``): its turn noise is CALIBRATED_TURN_FRACTION of the way to the steady filter's.

    After a found tyre mismatch the steady filter takes the rate filter's state for filter_follow_hold_m (``follow``),
    so the heading is the rate filter's, whose turn noise (16 % of each turn against the steady filter's 3.5 %) kept
    its offset's sigma near 2.3 deg on a highway and let it follow the compass's errors at every curve
    (highway/mismatch_1.5/106: 1.82 deg against its mismatch-free twin's 0.78).  Drives whose tyres match the file
    are untouched (``calibrated`` 0).  Fraction 0 / 0.3 / 0.5 / 0.7 / 1 on the matrix's tuning seeds: geometric mean
    0.844 / 0.836 / 0.833 / 0.834 / 0.854 deg (mismatch 2.5 %: 1.02 / 1.00 / 1.01 / 1.06 / 1.29); docs/tuning.md,
    stop 53.
    """
    turn_sigma = params.filter_turn_sigma + CALIBRATED_TURN_FRACTION * calibrated * (
        params.filter_steady_turn_sigma - params.filter_turn_sigma)
    return params._replace(filter_turn_sigma=turn_sigma)


def restart_together(params, rate_filter, steady, steady_lost_restart, clean_weight, drift_significant, calibrated):
    """One filter's restart restarts the other where the compass they share says both were wrong.

    * The rate filter follows the steady one's lost restart (``offset_filter.update``'s third item; the heading itself
      was wrong: a garage), unless the wheels' drift explains its own disagreement: a significant rate
      (``drift_significant``, bool) or a ratio the calibration has moved (``calibrated``, ``calibration.corrected``;
      a tyre mismatch, whose rate it must keep).  Left alone, a rate filter 58 deg off stayed under the 60 deg of its
      own lost restart for 250 s, learned a rate from it and the heading followed (urban/garage_start/110: 10.4 deg
      RMSE after the first minute, 5.0 with this).
    * The steady filter takes the rate filter's offset, restarted, when it is locked out of a compass (rejected for
      filter_reacquire_m) that the rate filter accepts (``clean_weight`` > 1/2) and the two are further apart than a
      shifted hard iron can turn the compass (FAR_RESTART_DEG): it lagged a drift too slow to be "large" (a hidden
      0.1 % tyre mismatch, 660 µrad/m, independent mixed seed 25: 30 deg off for 4 km, shown whenever the rate fell
      under the show rate).

    ``steady`` must already be updated with this sample (its ``rejected_m``); restarts carry each filter's own
    ``since_drift`` (``offset_filter.restarted_like``).  Returns (rate filter, steady filter, whether the rate filter
    followed the steady one's lost restart).
    """
    steady_params = _of.steady_params(params)
    rate_follows = computed_once(steady_lost_restart & ~drift_significant & (calibrated < 0.5))
    rate_filter = _of.OffsetState(jnp.where(rate_follows, _of.restarted_like(params, rate_filter, steady).vector,
                                            rate_filter.vector))
    resync = computed_once((steady.fields().rejected_m > params.filter_reacquire_m) & (clean_weight > 0.5)
                           & (jnp.abs(wrap(steady.delta - rate_filter.delta)) > deg(_of.FAR_RESTART_DEG)))
    steady = _of.OffsetState(jnp.where(resync, _of.restarted_like(steady_params, steady, rate_filter).vector,
                                       steady.vector))
    return rate_filter, steady, rate_follows


AGREED_STRETCH_Z = 2.0
"""The straight stretches agree with the rate filter's rate when their unapplied rate has its sign and is beyond this
many of its sigmas (``stretches_agree``; 1.0 let chance agreements show a hill's and a shifted hard iron's fake
rates: highway/hills/105 2.06 -> 4.63 deg, highway/hard_iron_shift/103 1.85 -> 6.01)."""
AGREED_SIGNIFICANCE = 2.0
"""While they agree, the heading shows the rate filter from this significance of its rate on (filter_rate_significance
otherwise), whatever the rate's size (``follow``)."""


def stretches_agree(params, calibration, rate_filter, track):
    """Whether the straight stretches (EP 0619873's pulse counts) see the drift the rate filter sees (bool): their
    unapplied rate (``calibration.stretches_rate``) has the rate filter's sign and is beyond AGREED_STRETCH_Z of its
    sigmas.  The two look at the tyres independently: the stretches count pulses on straight roads, the rate filter
    watches the compass against the wheels; a hill's dip error or a shifted hard iron fakes a rate in the compass
    only.  Where the seed is silent.  calibration: the calibration state; track: T (m)."""
    return _cal.stretches_see(params, calibration, rate_filter.beta, track, AGREED_STRETCH_Z)[0]


PERSIST_SIGN_Z = 1.0
"""``kept_sign`` counts metres while the rate filter's rate is beyond this many of its sigmas with one sign."""
PERSIST_FRACTION = 0.6
"""A drift persists when its rate has kept its sign for this fraction of the metres the rate filter followed the
compass (``persistent_drift``)."""
PERSIST_MIN_M = 3000.0
"""... and the rate filter has followed the compass this many metres more than the steady filter has rejected it."""
PERSIST_MAX_RATE = 4e-5
"""A persistent drift is small (rad/m): a ratio up to 60 ppm off the tyres'.  Its rate, and the largest significant
rate the rate filter has had since it started (``peak_rate``), stay under this: a hill's or a shifted hard iron's fake
rate starts large (-125 µrad/m on highway/hills/105) and decays."""
PEAK_Z = 1.5
"""``peak_rate`` records rates beyond this many of their sigmas."""
PERSIST_Z = 1.75
"""While a drift persists the heading shows the rate filter from this significance of its rate on, without the show
rate (``follow``)."""
_PEAK_ONEHOT = _of.one_hot("peak_rate")
_SIGN_ONEHOT = _of.one_hot("sign_m")


def kept_sign(rate_filter, d_t, absolute_ok):
    """The rate filter with its two counts of a persistent drift brought up to this sample (``persistent_drift``).

    ``sign_m`` (m, signed like the rate): metres of absolute headings (``absolute_ok``, bool) during which the rate has
    stayed beyond PERSIST_SIGN_Z of its sigmas with one sign; 0 as soon as it falls within them.  ``peak_rate``
    (rad/m): the largest |rate| the filter has had beyond PEAK_Z of its sigmas.  Both start at 0 when the filter
    (re)starts; ``sign_m`` also when the rate filter itself has rejected the compass for filter_reacquire_m
    (``offset_filter.update``, like ``accepted_m``).  A capture of the drift into the ratio does not reset
    ``peak_rate``: a captured mismatch's rate (over filter_follow_hold_rate) keeps ``persistent_drift`` off for the
    rest of the drive, and the residual the calibration leaves is shown by its own lower show rate instead
    (``follow``'s ``calibrated``).  d_t: this sample's distance (m).
    """
    f = rate_filter.fields()
    z = _rate.rate_z(f)
    step = jnp.where(absolute_ok, d_t, 0.0)
    kept = jnp.where(z > PERSIST_SIGN_Z, jnp.maximum(f.sign_m, 0.0) + step,
                     jnp.where(z < -PERSIST_SIGN_Z, jnp.minimum(f.sign_m, 0.0) - step, 0.0))
    peak = jnp.maximum(f.peak_rate, jnp.where(jnp.abs(z) > PEAK_Z, jnp.abs(f.beta), 0.0))
    return _of.added(_of.added(rate_filter, _SIGN_ONEHOT, kept - f.sign_m), _PEAK_ONEHOT, peak - f.peak_rate)


def persistent_drift(rate_filter, steady):
    """Whether the wheels drift slowly and for good, as a ratio a few tens of ppm off the tyres' makes them (bool).

    The rate filter's rate has kept its sign (``kept_sign``) over the last PERSIST_FRACTION of the metres it has
    followed the compass (``accepted_m``: at least PERSIST_MIN_M more than the steady filter has rejected it), and
    both that rate and the largest it ever had (``peak_rate``) are under PERSIST_MAX_RATE.  A tyre's drift is there
    from the first metre and stays; the compass's fake rates (dip on a hill, a hard iron that shifted) come large and
    go.  Where the seeds are silent.  Without this the heading shows a drift under filter_follow_show_rate only where
    the straight stretches agree (``stretches_agree``); on the independent simulator's highway drives with the file's
    ratio 30 ppm off (19 µrad/m) the steady filter lagged it by 2-8 deg (docs/tuning.md, stop 74).
    """
    f = rate_filter.fields()
    return (_rate.followed_since_before(f, steady, PERSIST_MIN_M)
            & (f.sign_m * f.beta > 0.0) & (jnp.abs(f.sign_m) >= PERSIST_FRACTION * f.accepted_m)
            & (jnp.abs(f.beta) <= PERSIST_MAX_RATE) & (f.peak_rate <= PERSIST_MAX_RATE))


def follow(params, steady, rate_filter, initializing, d_t, hold_on_drift=True, calibrated=0.0, agreed=False,
           persistent=False):
    """The steady F-DELTA and the heading it shows: drawn to the rate filter while the wheels drift.

    The rate filter (offset, rate, coloured error) follows a drifting wheel heading (a tyre mismatch
    before the calibration has caught it), but on clean drives the rate it learns from a compass with
    errors correlated over kilometres (dip on hills, anomalies) is noise that it integrates.  The
    steady filter has no rate; it gives the heading, and:

    * *shows* the rate filter's offset (and variance) while that filter's rate is significant
      (``follow_weight``) and larger than about filter_follow_show_rate, without taking it into its own
      state: a compass swing on a hill taken for a rate leaves the steady filter where it was once the
      rate is insignificant again;
    * *takes* the rate filter's state (rate taken out) for filter_follow_hold_m after the drift was
      confirmed: by the calibration, which restarts the hold when it moves the ratio (a capture of the
      drift or a recalibration: ``restart_hold``), or, with ``hold_on_drift`` (the calibration off), by a
      significant rate larger than filter_follow_hold_rate (``large_drift``).  After a drift the
      calibration takes out most of it within kilometres, and what remains (tens of µrad/m, no longer
      "significant") the rate filter still follows while the steady one would lag by degrees.

    ``agreed`` (``stretches_agree``): the straight stretches see the rate filter's drift too.  The heading then shows
    the rate filter from AGREED_SIGNIFICANCE of its rate on, without the show rate: a ratio 40 ppm off the tyres' (a
    file identified to 4e-5; 25 µrad/m of drift) left the independent simulator's highway drives 8.8 deg off with a
    clean compass, the rate filter knowing the drift (20 +- 9 µrad/m after 15 min) and the steady filter lagging it by
    5-8 deg (docs/tuning.md, stop 66).

    ``persistent`` (``persistent_drift``): the rate filter's rate is a small drift that has persisted.  The heading
    then shows the rate filter from PERSIST_Z of its rate on, without the show rate.  On the independent simulator's
    diagnosis drives (seeds 1-4 and 28-33) with the file's right dpp 30 ppm high / low, geometric mean 1.956 / 2.127
    deg -> 1.889 / 1.972 (highway 4.86 / 4.72 -> 4.22 / 3.49), the exact file and the matrix's seeds 101-106 unchanged
    (docs/tuning.md, stop 74).

    ``calibrated`` (``calibration.corrected``, in [0, 1]): the calibration has moved the ratio from the parameters'.
    The show rate is then CALIBRATED_SHOW_FRACTION of filter_follow_show_rate: the calibrated ratio's residual of
    1-3e-5 drifts the wheels by 10-30 µrad/m, below the show rate, and on a long highway the steady filter lagged it by
    degrees (independent simulator, the tyres' mismatch hidden from the parameters: docs/tuning.md, stop 47).  Drives
    whose tyres match the file keep the full show rate, which keeps a hill's fake rate out (highway/hills/105).

    Before stop 30 a significant rate was copied into the steady state too: hills drives of seeds 101-109
    (36) 1.41 deg against 1.23 deg now (docs/tuning.md, stop 30).  ``since_drift`` of the steady filter counts the
    metres since the hold last restarted; d_t (m) is this sample's distance.  Returns (steady state,
    shown: the steady state's OffsetFields with delta, p00 and disturbance blended towards the rate filter's,
    what the heading and ``bound`` read).
    """
    f = rate_filter.fields()
    z = jnp.zeros_like(f.beta)
    taken = f._replace(beta=z, **{f"p{min(i, 1)}{max(i, 1)}": z for i in range(len(_of.STATES))})
    w_rate = _rate.follow_weight(params, rate_filter)
    restart = _rate.large_drift(params, rate_filter) if hold_on_drift else False
    since = jnp.where(restart, 0.0, steady.since_drift + d_t)
    hold = jax.nn.sigmoid(20.0 * (1.0 - since / jnp.maximum(params.filter_follow_hold_m, 1e-9)))
    w = jnp.where(computed_once(initializing), 1.0, hold)
    # Field by field, then packed: blends of whole packed vectors cost XLA:CPU a transposed copy each.
    blended = _of.OffsetFields(*[s_ + w * (t_ - s_) for s_, t_ in zip(steady.fields(), taken)])
    # F-DELTA is an angle: blend the wrapped difference.
    s_delta = steady.delta
    blended = blended._replace(delta=wrap(s_delta + w * wrap(taken.delta - s_delta)), since_drift=since)
    # A significant but small rate is not shown: slow compass errors on hills fake one for kilometres.
    show_rate = params.filter_follow_show_rate * (1.0 - (1.0 - CALIBRATED_SHOW_FRACTION) * calibrated)
    w_rate = w_rate * jax.nn.sigmoid(_rate.FOLLOW_STEEPNESS * (jnp.abs(f.beta) - show_rate) / (show_rate + 1e-6))
    # Unless the stretches see the drift too (the compass alone does not fake it there), or it persists.
    for shown_small, significance in ((agreed, AGREED_SIGNIFICANCE), (persistent, PERSIST_Z)):
        w_rate = jnp.where(shown_small, jnp.maximum(w_rate, _rate.follow_weight(params, rate_filter, significance)),
                           w_rate)
    shown = blended._replace(delta=wrap(blended.delta + w_rate * wrap(taken.delta - blended.delta)),
                             p00=blended.p00 + w_rate * (taken.p00 - blended.p00),
                             disturbance=blended.disturbance + w_rate * (taken.disturbance - blended.disturbance))
    # ``shown`` stays unpacked: only its delta, p00 and disturbance are read.
    return _of.OffsetState.pack(blended), shown
