"""F-DELTA, US 4,734,863 FIG. 8E-8H: SDD and the factor F, the map selector, the filtered DELTA and EH.

Two forms, chosen by ``Config.robust``: ``robust_f_delta`` (issue 10: 8E before 8F, the rate and steady offset
filters of ``offset_filter``, B_E per heading learned from clean samples, the compass-shift learner) and
``seed_f_delta`` (the seed's first-order filter as first tuned on the project's simulator, B_E the running mean of
|B|: ``seed_expected_field``).  Both return the same dict of the new state's fields; ``model.step`` runs them.
"""

from __future__ import annotations

import jax.numpy as jnp

from . import calibration as _cal
from . import compass as _compass
from . import compass_noise as _noise
from . import compass_shift as _shift
from . import field_tilt as _field_tilt
from . import heading_filter as _hf
from . import follow as _follow
from . import offset_filter as _offset
from . import rate_significance as _rate
from . import wheel_step as _step
from .angles import safe_div, wrap
from .packed import computed_once, value_once
from .params import deg, field_magnitude_given


def learns_shift(config):
    """Config.compass_shift applies: the robust complementary mode without Config.hard_iron (the other modes are
    the matrix's single-sensor references and the Kalman filter, which read the compass as it is)."""
    return config.robust and config.compass_shift and not config.hard_iron and config.mode == "complementary"


def finds_wheel_steps(config):
    """Whether a step of the wheel heading is found from the compass's disagreement (jaxmodel/wheel_step.py): the
    robust complementary mode (the others are the matrix's single-sensor references and the Kalman filter)."""
    return config.robust and config.mode == "complementary"


def captures_drift(config):
    """Whether a large, significant drift of the rate filter is captured into the left/right ratio
    (``drift_capture.calibrate``): the robust complementary and Kalman modes with the calibration on (the other two are
    the matrix's single-sensor references).  In the Kalman mode the rate filter runs beside the Kalman filter,
    which reads its ratio and, while its drift is large, that rate (stop 48: a mismatch of 0.5-2.5 % left the
    Kalman filter 50-90 deg off without the capture and the release of its beta, 1.1-2.8 deg with them)."""
    return config.calibration and config.robust and config.mode in ("complementary", "kalman")


def robust_f_delta(params, state, config, sample, odo, h_c, h_c_raw, harmonics_of_raw, b_m, b_e, e_w, e_c,
                   compass_ok, wheel_heading, initialized, initializing):
    """FIG. 8E-8H as issue 10 runs them: SDD and F (8E, before the map selector 8F, so SD_N judges
    the compass), the map selector, and F-DELTA by the rate and steady offset filters of
    jaxmodel/offset_filter.py; B_E per heading learned from clean samples (claim 13).  ``h_c_raw``: H_C with the
    soft iron's deviation taken out; ``harmonics_of_raw``: ``soft_iron.harmonics`` of H_C before that, the heading
    the field's regression is read at.  Returns a dict of the new state's fields and the complementary heading
    EH = H_W + F-DELTA (rad)."""
    d_t, alpha = odo["d_t"], odo["alpha"]
    # FIG. 8 block 6 / 8E / 8E-A, in the figure's order (before 8F): every F_update_distance_m,
    # SDD of the compass-minus-wheel DELTA and F, so SD_N judges the compass, not the map.
    compass_delta = value_once(wrap(h_c - wheel_heading))
    compass_on = compass_ok & (initialized > 0.5)
    distance_since_F = state.distance_since_F + jnp.where(compass_on, d_t, 0.0)
    update_F = compass_on & (distance_since_F >= params.F_update_distance_m)
    history = jnp.where(update_F, jnp.concatenate([compass_delta[None], state.delta_history[:2]]),
                        state.delta_history)
    sdd = jnp.where(update_F, _hf.update_sdd(params, state.sdd, _hf.deviation_of_three(history)), state.sdd)
    factor = jnp.where(update_F, _hf.time_constant_factor(params, sdd, e_w, e_c), state.factor)
    distance_since_F = jnp.where(update_F, 0.0, distance_since_F)

    # FIG. 8F: map-heading selector, then DELTA.
    absolute, delta, map_used = _hf.select_absolute_heading(
        params, h_c, wheel_heading, state.heading, sample.map_heading, sample.map_valid,
        sample.compass_unreliable_area)
    absolute_ok = (compass_ok | map_used) & (initialized > 0.5)
    delta = value_once(delta)

    # FIG. 8G / 8H: the rate filter follows drifting wheels, the steady filter (no rate) gives F-DELTA.
    # The start's anchor is young for its first km of absolute headings: one straight road on a grade can be it.
    distance_filtered = state.distance_filtered + jnp.where(absolute_ok, d_t, 0.0)
    young = _offset.young(params, distance_filtered)
    calibrated = _cal.corrected(params, state.calibration)
    offset = _offset.predict(_follow.calibrated_rate_params(params, calibrated), state.offset, odo["AD"], d_t, alpha,
                             odo["turn_sigma"], odo["speed"])
    predicted_delta = offset.delta
    sigma = jnp.where(map_used, deg(params.kf_map_sigma_deg), _noise.compass_sigma(params, e_c, odo["turn_rate"]))
    drifting = _rate.drifting(params, offset)
    drift_significant = _rate.drifting_significantly(params, offset)
    ln_reference, has_reference = _field_tilt.reference(params, state.field_sum, state.field_count, state.soft_field,
                                                        harmonics_of_raw)
    tilt = _field_tilt.roll_reaching_heading(params, _field_tilt.tilt_gain(params, wheel_heading + state.steady.delta),
                                             has_reference)
    d_lost = _offset.lost_distance(d_t, odo["dt"])
    offset, clean_weight = _offset.update(params, offset, delta, sigma, d_t, 1.0,
                                          absolute_ok & ~initializing, drifting, tilt, d_lost, drift_significant,
                                          dt=odo["dt"], young=young, reading_dt=odo["reading_dt"])
    # |B| against B_E (given, else learned) measures the grade's and the roll's errors (jaxmodel/field_tilt.py), on
    # clean samples.
    field_ok = absolute_ok & ~initializing & compass_ok & ~map_used & (clean_weight > _field_tilt.CLEAN_WEIGHT)
    offset = _field_tilt.update(params, offset, b_m, tilt, field_ok, d_t, odo["dt"], ln_reference, has_reference,
                                odo["reading_dt"])
    offset = _offset.OffsetState(jnp.where(computed_once(initializing), _offset.start(params).vector, offset.vector))
    offset = _offset.count_since_large_drift(params, offset, state.offset, d_t)
    steady_params = _offset.steady_params(params)
    steady = _offset.predict(steady_params, state.steady, odo["AD"], d_t, alpha, odo["turn_sigma"], odo["speed"])
    # The steady filter is not hardened against a compass that disagrees because it lags the wheels' drift.
    lagging = drifting | _rate.steady_lags(params, offset, state.steady)
    steady, steady_weight, steady_lost_restart = _offset.update(steady_params, steady, delta, sigma, d_t, 1.0,
                                                                absolute_ok & ~initializing, lagging, tilt, d_lost,
                                                                drift_significant, dt=odo["dt"], young=young,
                                                                with_lost_restart=True, reading_dt=odo["reading_dt"])
    # A turn with a compass the steady filter accepts checked the anchor at another heading: ANCHOR_TURN_M metres a
    # radian (from the next sample on).  A rejected one did not (a start on a grade, contradicted after its first turn).
    distance_filtered = distance_filtered + jnp.where(absolute_ok & (steady_weight > 0.5),
                                                      _offset.ANCHOR_TURN_M * jnp.abs(alpha), 0.0)
    steady = _field_tilt.update(steady_params, steady, b_m, tilt, field_ok, d_t, odo["dt"], ln_reference,
                                has_reference, odo["reading_dt"])
    offset, steady, rate_follows = _follow.restart_together(params, offset, steady, steady_lost_restart, clean_weight,
                                                            drift_significant, calibrated)
    # The calibration confirms a drift by capturing it (``drift_capture.calibrate``); without it a large drift starts
    # the hold.  Its straight stretches seeing the drift too let a small one be shown.
    agreed = captures_drift(config) & _follow.stretches_agree(params, state.calibration, offset, odo["track"])
    offset = _follow.kept_sign(offset, d_t, absolute_ok & ~initializing)
    persistent = _follow.persistent_drift(offset, steady)
    steady, shown = _follow.follow(params, steady, offset, initializing, d_t, hold_on_drift=not captures_drift(config),
                                   calibrated=calibrated, agreed=agreed, persistent=persistent)
    f_delta = value_once(shown.delta)

    field_sum, field_count = state.field_sum, state.field_count
    # A lost filter's restart: F-DELTA moved beyond filter_reacquire_large_deg in one sample, or with the steady one.
    lost_restart = (jnp.abs(wrap(offset.delta - predicted_delta)) > deg(params.filter_reacquire_large_deg)
                    ) | rate_follows
    if learns_shift(config):
        # It says the compass the heading started from was disturbed (a garage): so was the B_E learned from it,
        # which the shift learner reads.
        field_sum = jnp.where(lost_restart, 0.0, field_sum)
        field_count = jnp.where(lost_restart, 0.0, field_count)
    field_sum, field_count = _compass.learn_field(
        params, field_sum, field_count, h_c_raw, b_m, b_e, d_t,
        compass_ok & (clean_weight > 0.5) | (compass_ok & (initialized < 0.5)))
    complementary = value_once(wrap(wheel_heading + f_delta))
    wheel_step, step, step_suspected = state.wheel_step, 0.0, False
    if finds_wheel_steps(config):
        # A compass that disagrees by one angle at every heading says the wheels stepped (jaxmodel/wheel_step.py).
        wheel_step, step, step_suspected = _step.update(
            wheel_step, wrap(compass_delta - f_delta), complementary, b_m, b_e, d_t,
            compass_ok & ~map_used & ~initializing & (initialized > 0.5) & ~drifting
            & (jnp.abs(odo["turn_rate"]) < _step.STEP_MAX_TURN_RATE) & (sample.compass_unreliable_area < 0.5),
            steady.rejected_m > 0.0)
    shift = state.shift
    if learns_shift(config):
        # The wheels carry EH while the compass is rejected; not while they drift (a tyre mismatch), while the
        # filter is lost (the heading itself may be wrong), in fast turns (roll) or on the map's heading.  Nor during
        # the follow hold after a drift (``follow.follow``): EH is then the rate filter's, and carries what the
        # wheels drifted before the calibration caught it (held-out mixed/mismatch_2.5/110 learned a 2-µT "shift"
        # from it: 1.08 -> 3.28 deg).
        following = steady.since_drift < params.filter_follow_hold_m
        learn = (compass_ok & (clean_weight < 0.5) & ~drifting & ~_offset.lost(params, offset.disturbance)
                 & (jnp.abs(odo["turn_rate"]) < _shift.SHIFT_MAX_TURN_RATE) & ~map_used & ~initializing
                 & (initialized > 0.5) & (sample.compass_unreliable_area < 0.5) & ~following & ~step_suspected)
        shift = _shift.update(shift, sample.compass_x - params.X0 - shift.ox, sample.compass_y - params.Y0 - shift.oy,
                              h_c_raw, complementary, b_e, d_t, learn, deg(params.rotation_deg))
    if finds_wheel_steps(config):
        # Both filters move by a step from the next sample on, their variance grown by its tolerance.
        offset = _step.stepped(offset, step)
        steady = _step.stepped(steady, step)
    return dict(compass_delta=compass_delta, distance_since_F=distance_since_F, history=history, sdd=sdd,
                factor=factor, absolute=absolute, map_used=map_used, distance_filtered=distance_filtered,
                offset=offset, steady=steady, shown=shown, f_delta=f_delta,
                complementary=complementary, field_sum=field_sum, field_count=field_count, shift=shift,
                clean_weight=clean_weight, sigma=sigma, field_restart=lost_restart & learns_shift(config),
                lost_restart=lost_restart, wheel_step=wheel_step,
                tilt_error=_field_tilt.heading_error(shown, tilt))


def seed_f_delta(params, state, sample, odo, h_c, field, e_w, e_c, compass_ok, wheel_heading, initialized,
                 initializing):
    """FIG. 8F, 8E and 8G-8H as first tuned on the project's simulator (Config.robust=False): the map
    selector, SDD and F, and the seed's first-order F-DELTA; B_E the running mean of |B| (bin 0).
    ``field`` is (field_sum, field_count) of ``seed_expected_field``.  Returns the same dict as
    ``robust_f_delta``."""
    d_t = odo["d_t"]
    field_sum, field_count = field
    # FIG. 8F (map selector) and DELTA (FIG. 8 block 5).
    absolute, delta, map_used = _hf.select_absolute_heading(
        params, h_c, wheel_heading, state.heading, sample.map_heading, sample.map_valid,
        sample.compass_unreliable_area)
    absolute_ok = (compass_ok | map_used) & (initialized > 0.5)

    # FIG. 8 block 6 / 8E / 8E-A: every F_update_distance_m, SDD and F.
    distance_since_F = state.distance_since_F + jnp.where(absolute_ok, d_t, 0.0)
    update_F = absolute_ok & (distance_since_F >= params.F_update_distance_m)
    history = jnp.where(update_F, jnp.concatenate([delta[None], state.delta_history[:2]]), state.delta_history)
    sdd = jnp.where(update_F, _hf.update_sdd(params, state.sdd, _hf.deviation_of_three(history)), state.sdd)
    factor = jnp.where(update_F, _hf.time_constant_factor(params, sdd, e_w, e_c), state.factor)
    distance_since_F = jnp.where(update_F, 0.0, distance_since_F)

    # FIG. 8G / 8H: F-DELTA and EH.
    distance_filtered = state.distance_filtered + jnp.where(absolute_ok, d_t, 0.0)
    gain = _hf.filter_gain(params, d_t, factor, distance_filtered)
    f_delta = jnp.where(initializing, 0.0,
                        jnp.where(absolute_ok, _hf.update_f_delta(state.f_delta, delta, gain), state.f_delta))
    return dict(compass_delta=wrap(h_c - wheel_heading), distance_since_F=distance_since_F, history=history, sdd=sdd,
                factor=factor, absolute=absolute, map_used=map_used, distance_filtered=distance_filtered,
                offset=state.offset, steady=state.steady, f_delta=f_delta,
                complementary=wrap(wheel_heading + f_delta), field_sum=field_sum, field_count=field_count)


def seed_expected_field(params, state, b_m, compass_ok):
    """B_E of the seed filter (µT): the parameter when given (> 0), else the running mean of |B| (kept in
    bin 0).  Returns (B_E, (field_sum, field_count))."""
    field_sum = state.field_sum.at[0].add(jnp.where(compass_ok, b_m, 0.0))
    field_count = state.field_count.at[0].add(jnp.where(compass_ok, 1.0, 0.0))
    learned = safe_div(field_sum[0], field_count[0], fallback=1.0)
    return jnp.where(field_magnitude_given(params), params.field_magnitude, learned), (field_sum, field_count)
