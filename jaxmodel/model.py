"""The estimator: ``init_state``, ``step`` and ``run`` (SPEC §6).

``step(params, state, sample, config) -> (state, output)`` processes one sensor sample in the
order of US 4,734,863 FIG. 8: compass heading (8A), wheel heading (8B, with US 4,788,645
eq. 8 and 14), compass and wheel error bounds (8C, 8D), DELTA, the factor F every
F_update_distance_m (8E, 8E/A), the map-heading selector (8F), F-DELTA (8G) and EH (8H);
then the refinement of a (US 4,788,645 eq. 9-13), the left/right calibration (EP 0619873),
the Kalman mode (US 4,680,715) when selected, and the dead-reckoned position.

``run`` is a ``lax.scan`` of ``step`` over the samples of one drive; ``jax.vmap(run,
in_axes=(None, 0))`` runs a batch of drives (``run_batch``).  Everything is float64.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from . import calibration as _cal
from . import compass as _compass
from . import compass_shift as _shift
from . import dequantize as _dequant
from . import drift_capture as _capture
from . import f_delta as _fdelta
from . import hard_iron as _hard_iron
from . import heading_filter as _hf
from . import kalman as _kalman
from . import odometer as _odo
from . import offset_filter as _offset
from . import plausibility as _guard
from . import refine as _refine
from . import soft_iron as _soft
from . import soft_iron_field as _sfield
from . import track as _track
from . import wheel_step as _wheel_step
from .angles import wrap
from .packed import value_once
from .params import deg

MODES = ("complementary", "odometer", "compass", "kalman")


class Config(NamedTuple):
    """Static (compile-time) choices.  Hashable, passed as a static argument to jit.

    mode: 'complementary' (default, US 4,734,863), 'odometer' (wheel heading started from the
    compass), 'compass', or 'kalman' (US 4,680,715).  refine_a: online refinement of a
    (eq. 9-13).  calibration: left/right dpp calibration (EP 0619873).  track: 'closed_form'
    (eq. 14) or 'table' (claims 15-16).  robust (the default, issue 10): the odometer guard
    of jaxmodel/plausibility.py in every mode, F-DELTA by the Kalman filter of
    jaxmodel/offset_filter.py (offset, rate per metre, coloured compass error, turn scale error; the
    heading from its rate-free steady twin while the rate is insignificant), B_E per heading, FIG. 8E before 8F,
    calibration that captures up to cal_max_correction, reliability 0 before any absolute heading.  robust=False:
    the seed's first-order filter as first tuned on the project's own simulator (docs/tuning.md), kept for
    comparison; it was chosen against by the scenario matrix (a 1 % tyre mismatch puts it 100°
    off, one pulse burst 10°).  hard_iron: online estimate of the compass offsets X0/Y0 from the
    field seen while turning (jaxmodel/hard_iron.py), started from the parameters' X0/Y0; off by default.
    compass_shift (robust, without hard_iron): a shifted hard iron found from the wheels' heading while the
    filter rejects the compass (jaxmodel/compass_shift.py).  dequantize (robust, every mode but 'compass'): the
    counts' quantization taken out of the heading output (jaxmodel/dequantize.py).  soft_iron (robust, every mode but
    'compass'): the compass's soft-iron deviation read from the field's magnitude per heading
    (jaxmodel/soft_iron_field.py), less what a calibrated deviation table took out already, the rest learned from
    the wheels' turns (jaxmodel/soft_iron.py), taken out of H_C.
    """

    mode: str = "complementary"
    refine_a: bool = True
    calibration: bool = True
    track: str = "closed_form"
    robust: bool = True
    hard_iron: bool = False
    compass_shift: bool = True
    dequantize: bool = True
    soft_iron: bool = True


DEFAULT_CONFIG = Config()


class Inputs(NamedTuple):
    """One sensor sample (scalars) or a drive (arrays of shape (N,) or (batch, N)).

    Pulse counters are float64 counts (exact up to 2**53). Angles in rad, positions in m.
    Flags are 0.0/1.0. Optional inputs default to 0 / NaN via ``make_inputs``.
    """

    time_s: jnp.ndarray
    left_pulses: jnp.ndarray
    right_pulses: jnp.ndarray
    compass_x: jnp.ndarray
    compass_y: jnp.ndarray
    map_heading: jnp.ndarray
    map_valid: jnp.ndarray
    compass_unreliable_area: jnp.ndarray
    fix_east_m: jnp.ndarray
    fix_north_m: jnp.ndarray
    fix_valid: jnp.ndarray


def make_inputs(time_s, left_pulses, right_pulses, compass_x, compass_y, map_heading=None, map_valid=None,
                compass_unreliable_area=None, fix_east_m=None, fix_north_m=None, fix_valid=None) -> Inputs:
    """Inputs with float64 arrays; absent optional columns become 0 (flags) or NaN-free zeros."""
    time_s = jnp.asarray(time_s, jnp.float64)
    zeros = jnp.zeros_like(time_s)

    def f(v):
        return zeros if v is None else jnp.asarray(v, jnp.float64)

    return Inputs(time_s, f(left_pulses), f(right_pulses), f(compass_x), f(compass_y), f(map_heading), f(map_valid),
                  f(compass_unreliable_area), f(fix_east_m), f(fix_north_m), f(fix_valid))


class State(NamedTuple):
    """Filter state (all float64 scalars except ``delta_history``, shape (3,))."""

    started: jnp.ndarray          # 1.0 once the first sample set the counter references
    initialized: jnp.ndarray      # 1.0 once a valid compass sample (Kalman mode: or a fix) started the wheel heading
    last_time: jnp.ndarray        # s
    last_left: jnp.ndarray        # counts
    last_right: jnp.ndarray       # counts
    last_count_time: jnp.ndarray  # s, time of the last sample whose counts changed (held counters)
    speed: jnp.ndarray            # m/s
    window_dD: jnp.ndarray        # exponentially windowed sum of dD, m
    window_AD: jnp.ndarray        # exponentially windowed sum of |AD|, m
    interval_dD: jnp.ndarray      # over the current curvature interval: sum of dD / (1 + a V^2), m
    interval_signed_dD: jnp.ndarray  # sum of dD signed as the travel, m
    interval_AD: jnp.ndarray      # sum of |AD|, m
    interval_turn: jnp.ndarray    # the interval's wheel turn as evaluated at the previous sample, rad
    wheel_heading: jnp.ndarray    # H_W, rad
    compass_heading: jnp.ndarray  # last valid H_C, rad
    f_delta: jnp.ndarray          # F-DELTA, rad
    heading: jnp.ndarray          # EH, rad (output of the selected mode)
    e_w: jnp.ndarray              # E_W, rad
    e_c: jnp.ndarray              # last E_C, rad
    sdd: jnp.ndarray              # SDD, rad
    factor: jnp.ndarray           # F
    delta_history: jnp.ndarray    # last three DELTA at F updates, newest first, rad
    distance_since_F: jnp.ndarray  # m since the last update of F
    distance_filtered: jnp.ndarray  # m driven with the filter running (start-up floor of the gain; robust: + turns)
    field_sum: jnp.ndarray        # (FIELD_BINS,) distance-weighted sums of |B| per heading bin (learned B_E)
    field_count: jnp.ndarray      # (FIELD_BINS,) their weights, m
    a: jnp.ndarray                # current velocity coefficient, s^2/m^2
    x: jnp.ndarray                # east, m
    y: jnp.ndarray                # north, m
    distance: jnp.ndarray         # total distance, m
    refine: _refine.RefineState
    calibration: _cal.CalibrationState
    kalman: _kalman.KalmanState
    guard: _guard.GuardState
    offset: _offset.OffsetState
    steady: _offset.OffsetState   # F-DELTA without a rate state (the heading while the rate is insignificant)
    hard_iron: _hard_iron.HardIronState  # online X0/Y0 (Config.hard_iron; else carried unchanged)
    shift: _shift.ShiftState      # a shifted hard iron learned while the compass is rejected (Config.compass_shift)
    wheel_step: _wheel_step.WheelStepState  # a rejection episode's disagreement (jaxmodel/wheel_step.py)
    dequant: _dequant.DequantState  # the wheel heading between pulses (robust modes that turn with the wheels)
    soft_iron: _soft.SoftIronState  # the compass's soft-iron deviation learned from turns (Config.soft_iron)
    soft_field: _sfield.SoftFieldState  # the soft iron read from the field magnitude per heading (Config.soft_iron)
    stale: _compass.StaleState    # the last raw compass reading and the wheels' turn since it changed (robust modes)


class Outputs(NamedTuple):
    """Per-sample outputs; angles wrapped to (-pi, pi]."""

    heading: jnp.ndarray              # estimate of the selected mode, rad
    wheel_heading: jnp.ndarray        # H_W, rad
    compass_heading: jnp.ndarray      # H_C (last valid when this sample's compass is invalid), rad
    x: jnp.ndarray                    # east, m
    y: jnp.ndarray                    # north, m
    speed: jnp.ndarray                # m/s
    a: jnp.ndarray                    # current velocity coefficient, s^2/m^2
    heading_reliability: jnp.ndarray  # (0, 1]
    heading_bound: jnp.ndarray        # rad
    compass_valid: jnp.ndarray        # 1.0 if this sample's compass was used
    odometer_valid: jnp.ndarray       # 1.0 if this sample's pulse counts were plausible
    curvature: jnp.ndarray            # windowed dD/AD
    effective_track: jnp.ndarray      # T used in eq. (8), m
    factor: jnp.ndarray               # F
    f_delta: jnp.ndarray              # F-DELTA, rad
    e_c: jnp.ndarray                  # rad
    e_w: jnp.ndarray                  # rad
    map_used: jnp.ndarray             # 1.0 if the map heading replaced the compass
    dpp_ratio: jnp.ndarray            # dpp_right / dpp_left
    distance: jnp.ndarray             # m
    initialized: jnp.ndarray          # 1.0 once a valid compass sample (Kalman mode: or the fixes) started the heading


def init_state(params) -> State:
    """State before the first sample; the first sample sets the counter and time references."""
    z = jnp.zeros((), jnp.float64)
    one = jnp.ones((), jnp.float64)
    return State(
        started=z, initialized=z, last_time=z, last_left=z, last_right=z, last_count_time=z, speed=z, window_dD=z,
        window_AD=z, interval_dD=z, interval_signed_dD=z, interval_AD=z, interval_turn=z,
        wheel_heading=z, compass_heading=z, f_delta=z, heading=z, e_w=z, e_c=z, sdd=z, factor=one,
        delta_history=jnp.zeros((3,), jnp.float64), distance_since_F=z, distance_filtered=z,
        field_sum=jnp.zeros((_compass.FIELD_BINS,), jnp.float64),
        field_count=jnp.zeros((_compass.FIELD_BINS,), jnp.float64), a=jnp.asarray(params.a, jnp.float64), x=z, y=z,
        distance=z,
        refine=_refine.init_refine_state(), calibration=_cal.init_calibration_state(params),
        kalman=_kalman.init_kalman_state(params), guard=_guard.init_guard_state(),
        offset=_offset.init_offset_state(params), steady=_offset.init_offset_state(_offset.steady_params(params)),
        hard_iron=_hard_iron.init_hard_iron_state(params), shift=_shift.init_shift_state(),
        wheel_step=_wheel_step.init_wheel_step_state(),
        dequant=_dequant.init_dequant_state(), soft_iron=_soft.init_soft_iron_state(),
        soft_field=_sfield.init_soft_field_state(), stale=_compass.init_stale_state(),
    )


def _compass_stage(params, state, sample, config, d_t, alpha):
    """FIG. 8A: compass heading, field magnitude and validity (offsets learned online with
    Config.hard_iron, whose first accepted fit restarts the heading and B_E).  Returns (state,
    hard_iron state, H_C raw (rad), |B| (µT), compass_ok, restart: this sample's fit restarted them)."""
    if not config.hard_iron:
        if _fdelta.learns_shift(config):
            params = params._replace(X0=params.X0 + state.shift.ox, Y0=params.Y0 + state.shift.oy)
        h_c_raw, b_m, compass_ok = _compass.compass_heading(params, sample.compass_x, sample.compass_y)
        return state, state.hard_iron, h_c_raw, b_m, compass_ok, jnp.zeros_like(compass_ok)
    hard_iron, restart = _hard_iron.update(params, state.hard_iron, sample.compass_x, sample.compass_y, d_t,
                                           alpha, sample.compass_unreliable_area < 0.5)
    x0, y0 = _hard_iron.offsets(hard_iron)
    h_c_raw, b_m, compass_ok = _compass.compass_heading(params._replace(X0=x0, Y0=y0), sample.compass_x,
                                                        sample.compass_y)
    state = state._replace(initialized=jnp.where(restart, 0.0, state.initialized),
                           field_sum=jnp.where(restart, 0.0, state.field_sum),
                           field_count=jnp.where(restart, 0.0, state.field_count))
    return state, hard_iron, h_c_raw, b_m, compass_ok, restart


def _learns_soft_iron(config):
    """Whether the soft iron's deviation is learned and taken out of the compass: robust modes but 'compass'."""
    return config.soft_iron and config.robust and config.mode != "compass"


def _learn_soft_iron(params, state, fd, compass_less_wheels, harmonics, alpha, d_t, compass_ok, initialized,
                     initializing):
    """The soft iron's deviation learned from the wheels' turns (jaxmodel/soft_iron.py) after F-DELTA (``fd``, the
    robust F-DELTA's dict).  ``compass_less_wheels`` (rad): the compass heading with the field's deviation taken out,
    less the wheel heading.  Returns the soft_iron state."""
    # Only where the filter took the compass as clean, and only from the turns of an identified vehicle: with
    # the scale state on (an unidentified one) every turn is ~10 % wrong, and a grid's turns at few headings
    # put that into (p, q) too (urban/baseline/201 with nominal parameters: 1.77 -> 2.14 deg).  The speed-scaled
    # state of a vehicle given but for its a (filter_scale_speed_ref > 0) is a few per cent at most at town speeds:
    # learning stays on (stop 83, independent diagnosis drives with a dropped, prior sigma 0.015: 1.223 -> 1.196 deg).
    clean = (compass_ok & (fd["clean_weight"] > 0.5) & (initialized > 0.5) & ~initializing & ~fd["map_used"]
             & ((params.filter_scale_sigma0 <= 0.0) | (params.filter_scale_speed_ref > 0.0)))
    return _soft.update(state.soft_iron, wrap(compass_less_wheels), harmonics, alpha, d_t, clean,
                        deg(params.filter_compass_sigma_deg) / fd["sigma"])


def _read_soft_field(state, config, fd, harmonics, d_t, b_m, b_e, compass_ok, hard_iron_restart):
    """The regression of ln|B| on the heading's harmonics (jaxmodel/soft_iron_field.py) after F-DELTA: the soft iron
    it reads, and the reference |B| is read against as the grade's and the roll's errors (jaxmodel/field_tilt.py),
    which every robust mode reads, whether or not the soft iron is taken out of the heading."""
    # The sums start again with B_E per heading (a hard-iron or a lost filter's restart empties its bins) and
    # when the offsets shift.
    restart = hard_iron_restart | fd["field_restart"]
    if _fdelta.learns_shift(config):
        restart = restart | (fd["shift"].ox != state.shift.ox) | (fd["shift"].oy != state.shift.oy)
    return _sfield.update(state.soft_field, harmonics, b_m, b_e, d_t, compass_ok & (d_t > 0.0), restart)


def _soft_iron_taken_out(params, state, config, h_c_raw, harmonics):
    """(H_C as read less the deviation the field's magnitude per heading says, H_C less the soft iron the wheels'
    turns learned too) (rad); without ``_learns_soft_iron``: (h_c_raw, h_c_raw).  ``harmonics``: those of the raw
    H_C (``soft_iron.harmonics``), at which both deviations are read.

    The soft iron's deviation read from B_E per heading (jaxmodel/soft_iron_field.py), then what the wheels' turns
    learned of the rest (jaxmodel/soft_iron.py), taken out of the compass."""
    if not _learns_soft_iron(config):
        return h_c_raw, h_c_raw
    # Less what the deviation table's second harmonic took out already (a calibrated compass).
    table = _sfield.table_deviation(params.deviation_deg, deg(params.variation_deg - params.rotation_deg))
    h_c_read = wrap(h_c_raw - _sfield.deviation(state.soft_field, harmonics, table))
    return h_c_read, wrap(h_c_read - _soft.deviation(state.soft_iron, harmonics))


def _dequantized(state, config, odo, heading, initializing, initialized):
    """(dequantizer state, the heading output with the counts' quantization taken out: jaxmodel/dequantize.py) in
    the robust modes that turn with the wheels (Config.dequantize); H_W stays as counted."""
    if not (config.robust and config.dequantize and config.mode != "compass"):
        return state.dequant, heading
    dequant, epsilon = _dequant.update(state.dequant, odo["alpha"], odo["dt"], odo["d_t"] > 0.0,
                                       _dequant.pulse_heading(odo["dpp"], odo["track"]),
                                       initializing | (initialized < 0.5), dt_moved=odo["dt_counts"])
    return dequant, wrap(heading + epsilon)


def _dead_reckoned(state, heading, distance):
    """Position (m; x east, y north, heading from north) moved ``distance`` (m) at the mid-sample heading."""
    mid = wrap(state.heading + 0.5 * wrap(heading - state.heading))
    mid = jnp.where(state.started > 0.5, mid, heading)
    return state.x + distance * jnp.sin(mid), state.y + distance * jnp.cos(mid)


def _heading_bound(params, config, fd, kalman_state, wheel_heading, h_c, e_w, e_c, initialized):
    """The heading's error bound (rad) in ``config.mode``: the robust F-DELTA's (offset_filter.bound) or FIG. 8's
    (SDD, E_W, E_C), the Kalman filter's own, and for the single-sensor modes the fused bound plus their distance
    from the fused heading."""
    if config.robust:
        bound = _offset.bound(params, fd["shown"], initialized)
    else:
        bound = _hf.heading_bound(fd["sdd"], e_w, e_c)
    if config.mode == "kalman":
        bound = _kalman.bound(params, kalman_state, initialized)
    elif config.mode in ("odometer", "compass"):
        # The single-sensor modes' heading is the fused one less their distance from it (triangle inequality): the
        # wheels after an unknown tyre mismatch, 150 deg off, had the fused heading's reliability (stop 48).
        single = wheel_heading if config.mode == "odometer" else h_c
        bound = jnp.minimum(bound + jnp.abs(wrap(single - fd["complementary"])), _offset.UNINITIALIZED_BOUND)
    return bound


def _kalman_compass(fd, h_c):
    """The compass course the Kalman mode measures (rad): H_C less the grade's and the roll's error that the robust
    F-DELTA estimated (``field_tilt.heading_error``; the seed filter's F-DELTA has none: H_C as it is).

    US 4,680,715 step 2 takes the known deterministic course errors out of the compass course before the filter (the
    deviation table, the soft iron's deviation learned beside F-DELTA, here also the tilt); its dth1, one
    Gauss-Markov error for every heading, cannot tell a heading-dependent error from the wheels' offset.  On the
    independent simulator's drives (hard-iron residual, dip on grades) the Kalman mode without fixes followed the
    compass 2-5 deg off for minutes where the default, which models them, did not (docs/tuning.md, stop 90)."""
    if "tilt_error" not in fd:
        return h_c
    return wrap(h_c - fd["tilt_error"])


def step(params, state: State, sample: Inputs, config: Config = DEFAULT_CONFIG, track_table=None):
    """Process one sample; returns (new state, Outputs).  See the module docstring for the order.

    ``track_table`` is the table of ``track.effective_track_table`` when config.track == 'table'
    (``run`` builds it once per drive; ``step`` builds it itself if it is missing).
    """
    if config.mode not in MODES:
        raise ValueError(f"unknown mode {config.mode!r}; expected one of {', '.join(MODES)}")
    if config.track == "table" and track_table is None:
        track_table = _track.effective_track_table(params.P, params.B, params.T_F, params.curvature_clip)
    elif config.track not in ("table", "closed_form"):
        raise ValueError(f"unknown track model {config.track!r}; expected 'closed_form' or 'table'")
    robust = config.robust
    odo = _odo.odometer(params, state, sample, track_table, robust)
    d_t, alpha = odo["d_t"], odo["alpha"]
    stale = state.stale
    if robust:
        # A reading repeated while the wheels turn is a logger's held value: missing (compass.stale_check).
        stale, held = _compass.stale_check(stale, sample.compass_x, sample.compass_y, alpha)
        sample = sample._replace(compass_x=jnp.where(held, jnp.nan, sample.compass_x),
                                 compass_y=jnp.where(held, jnp.nan, sample.compass_y))
        stale, reading_dt = _compass.reading_interval(
            stale, odo["dt"], jnp.isfinite(sample.compass_x) & jnp.isfinite(sample.compass_y))
        odo = dict(odo, reading_dt=reading_dt)

    # FIG. 8A / 8C: compass heading, field magnitude, error bound (B_E per heading, claim 13).
    state, hard_iron, h_c_raw, b_m, compass_ok, hard_iron_restart = _compass_stage(params, state, sample, config,
                                                                                  d_t, alpha)
    if robust:
        # Read by most of the step: computed once (packed.value_once).
        h_c_raw, b_m = value_once(h_c_raw), value_once(b_m)
        b_e = value_once(_compass.expected_field(params, state.field_sum, state.field_count, h_c_raw, b_m))
    else:
        b_e, seed_field = _fdelta.seed_expected_field(params, state, b_m, compass_ok)
    e_c = jnp.where(compass_ok, _compass.compass_error_bound(params, b_m, b_e), state.e_c)
    # The raw heading's harmonics, once per sample: the soft-iron regressions learn on them, and the reference |B| is
    # read at them (the raw H_C is 0 where the compass is invalid: never a NaN).
    harmonics = _soft.harmonics(h_c_raw)
    h_c_read, h_c_raw = _soft_iron_taken_out(params, state, config, h_c_raw, harmonics)
    h_c = jnp.where(compass_ok, h_c_raw, state.compass_heading)

    # FIG. 8B: wheel heading; the first valid compass sample starts it (odometer mode too), in the Kalman mode also
    # the fixes' alignment with the wheels' track when no compass has (SPEC §8, jaxmodel/fix_alignment.py).
    initializing = compass_ok & (state.initialized < 0.5)
    wheel_heading = jnp.where(initializing, h_c_raw, wrap(state.wheel_heading + alpha))
    kalman_before = state.kalman
    if config.mode == "kalman":
        alignment, started, realigned, rotation, rotation_sigma = _kalman.align_before(
            params, state.kalman, dt=odo["dt"], distance=odo["AD"], alpha=alpha, wheel_heading=state.wheel_heading,
            fix_east=sample.fix_east_m, fix_north=sample.fix_north_m, fix_valid=sample.fix_valid,
            uninitialized=(state.initialized < 0.5) & ~initializing, compass_ok=compass_ok)
        kalman_before = state.kalman._replace(alignment=alignment)
        wheel_heading = jnp.where(started, wrap(wheel_heading + rotation), wheel_heading)
        initializing = initializing | started
    initialized = jnp.where(initializing, 1.0, state.initialized)
    if robust:
        h_c, wheel_heading = value_once(h_c), value_once(wheel_heading)

    # FIG. 8D: wheel error bound.
    e_w = _hf.wheel_error_bound(params, state.e_w, alpha, d_t)

    # FIG. 8E-8H: SDD, F, the map selector and F-DELTA.
    if robust:
        fd = _fdelta.robust_f_delta(params, state, config, sample, odo, h_c, h_c_raw, harmonics, b_m, b_e, e_w, e_c,
                                    compass_ok, wheel_heading, initialized, initializing)
    else:
        fd = _fdelta.seed_f_delta(params, state, sample, odo, h_c, seed_field, e_w, e_c, compass_ok,
                                  wheel_heading, initialized, initializing)

    soft_iron, soft_field = state.soft_iron, state.soft_field
    if robust and config.mode != "compass":
        if _learns_soft_iron(config):
            soft_iron = _learn_soft_iron(params, state, fd, h_c_read - wheel_heading, harmonics, alpha, d_t,
                                         compass_ok, initialized, initializing)
        soft_field = _read_soft_field(state, config, fd, harmonics, d_t, b_m, b_e, compass_ok, hard_iron_restart)

    # US 4,788,645 eq. (9)-(13): refinement of a (uses the compass, not the map).
    refine_state, a = _refine.refine_step(
        params, state.refine, state.a, alpha=alpha, delta=fd["compass_delta"], d_t=d_t, speed=odo["speed"],
        curvature=odo["curvature"], e_c=e_c, compass_ok=compass_ok & (initialized > 0.5), enabled=config.refine_a)

    # EP 0619873: left/right distance-per-pulse calibration.
    cal_state, offset, steady, rate_change = _capture.calibrate(
        params, state.calibration, config, odo, h_c, compass_ok, fd["offset"], fd["steady"], initialized)

    # US 4,680,715: Kalman mode (its own heading and position).
    kalman_state, kalman_heading, kalman_x, kalman_y = _kalman.kalman_step(
        params, kalman_before, dt=odo["dt"], dt_counts=odo["dt_counts"], held=odo["held"], distance=odo["AD"],
        alpha=alpha, wheel_heading=wheel_heading,
        compass_heading=_kalman_compass(fd, h_c), compass_ok=compass_ok & (initialized > 0.5), e_c=e_c,
        fix_east=sample.fix_east_m,
        fix_north=sample.fix_north_m, fix_valid=sample.fix_valid, odometer_ok=odo["kept"],
        initialized=initialized, map_heading=fd["absolute"], map_used=fd["map_used"], enabled=config.mode == "kalman",
        rate_change=rate_change, rate_variance=_kalman.released_rate_variance(params, offset, kalman_before),
        lost_elsewhere=fd.get("lost_restart", False), reading_dt=odo.get("reading_dt"), turn_sigma=odo["turn_sigma"])
    if config.mode == "kalman":
        kalman_state, kalman_heading, kalman_x, kalman_y = _kalman.align_after(
            params, kalman_state, kalman_heading, started, realigned, rotation, rotation_sigma,
            sample.fix_east_m, sample.fix_north_m, odo["track"])

    heading = {"complementary": fd["complementary"], "odometer": wheel_heading, "compass": h_c,
               "kalman": kalman_heading}[config.mode]
    dequant, heading = _dequantized(state, config, odo, heading, initializing, initialized)

    if config.mode == "kalman":
        x, y = kalman_x, kalman_y
    else:
        x, y = _dead_reckoned(state, heading, odo["AD"])
    bound = _heading_bound(params, config, fd, kalman_state, wheel_heading, h_c, e_w, e_c, initialized)
    # Before the heading is initialized the bound is UNINITIALIZED_BOUND (180 deg): the reliability is then its
    # smallest, 1 / (1 + 180 / reliability_scale_deg), inside SPEC §8's (0, 1] (exactly 0 before stop 44).
    reliability = _hf.reliability(params, bound)
    new_state = State(
        started=jnp.ones((), jnp.float64),
        initialized=initialized,
        last_time=jnp.where(jnp.isfinite(sample.time_s) & ((sample.time_s > state.last_time) | (state.started < 0.5)),
                            sample.time_s, state.last_time),
        last_left=odo["left"], last_right=odo["right"], last_count_time=odo["last_count_time"], speed=odo["speed"],
        window_dD=odo["window_dD"], window_AD=odo["window_AD"], **odo["interval"], wheel_heading=wheel_heading,
        compass_heading=h_c,
        f_delta=fd["f_delta"], heading=heading, e_w=e_w, e_c=e_c, sdd=fd["sdd"], factor=fd["factor"],
        delta_history=fd["history"], distance_since_F=fd["distance_since_F"],
        distance_filtered=fd["distance_filtered"], field_sum=fd["field_sum"], field_count=fd["field_count"], a=a,
        x=x, y=y, distance=state.distance + d_t, refine=refine_state, calibration=cal_state, kalman=kalman_state,
        guard=odo["guard"], offset=offset, steady=steady, hard_iron=hard_iron, shift=fd.get("shift", state.shift),
        wheel_step=fd.get("wheel_step", state.wheel_step),
        dequant=dequant, soft_iron=soft_iron, soft_field=soft_field, stale=stale,
    )
    out = Outputs(
        heading=heading, wheel_heading=wheel_heading, compass_heading=h_c, x=x, y=y, speed=odo["speed"], a=a,
        heading_reliability=reliability, heading_bound=bound,
        compass_valid=jnp.where(compass_ok, 1.0, 0.0), odometer_valid=jnp.where(odo["plausible"], 1.0, 0.0),
        curvature=odo["curvature"], effective_track=odo["track"], factor=fd["factor"], f_delta=fd["f_delta"], e_c=e_c,
        e_w=e_w, map_used=jnp.where(fd["map_used"], 1.0, 0.0),
        dpp_ratio=cal_state.dpp_right / cal_state.dpp_left, distance=new_state.distance, initialized=initialized,
    )
    return new_state, out


def run_from(params, state: State, inputs: Inputs, config: Config = DEFAULT_CONFIG):
    """Scan ``step`` over the samples of ``inputs`` (leaves of shape (N,)) from ``state``.

    The carry is the State pytree itself: measured on XLA:CPU, flattening it into one vector
    (ravel_pytree) made both the forward pass and value_and_grad ~9x slower on this 2-core CPU.
    Returns (final state, Outputs with leaves of shape (N,)).
    """
    table = None
    if config.track == "table":
        table = _track.effective_track_table(params.P, params.B, params.T_F, params.curvature_clip)

    def body(carry, sample):
        return step(params, carry, sample, config, table)

    return jax.lax.scan(body, state, inputs)


@partial(jax.jit, static_argnames=("config",))
def run(params, inputs: Inputs, config: Config = DEFAULT_CONFIG) -> Outputs:
    """Outputs for one drive: ``lax.scan`` of ``step`` from ``init_state(params)``. Pure; jit-ed."""
    return run_from(params, init_state(params), inputs, config)[1]


@partial(jax.jit, static_argnames=("config",))
def run_batch(params, inputs: Inputs, config: Config = DEFAULT_CONFIG) -> Outputs:
    """``run`` vmapped over a leading drive axis of ``inputs`` (shared params)."""
    return jax.vmap(lambda inp: run_from(params, init_state(params), inp, config)[1])(inputs)
