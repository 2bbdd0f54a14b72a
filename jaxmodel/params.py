"""Vehicle and filter parameters: one table, one NamedTuple, one JSON schema.

Every parameter is declared exactly once, in ``PARAMETER_TABLE``: its key (the
flat JSON key of SPEC §3 and the FMU variable name), default, unit and meaning.
``Params`` is a NamedTuple of float64 arrays built from that table, so it is a
pytree that can be jit-ed, vmap-ed and differentiated.  ``sensor_axle`` is the
only non-numeric key: ``"front"`` is stored as 1.0 and ``"rear"`` as 0.0.

The JSON file is flat (SPEC §3).  Unknown keys are refused with an error naming
them; missing keys take the documented defaults below.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

DEVIATION_TABLE_SIZE = 36
"""Compass deviation table entries, one per 10° of raw heading (US 4,734,863 FIG. 8A block 4)."""


class ParamSpec(NamedTuple):
    key: str
    default: Any
    unit: str
    description: str


# fmt: off
PARAMETER_TABLE: tuple[ParamSpec, ...] = (
    # --- vehicle geometry, US 4,788,645 -------------------------------------------------
    ParamSpec("sensor_axle", "front", "", "wheel sensors on the 'front' (Ackerman, eq. 14) or 'rear' axle (T = T_R)"),
    # Seed defect: P is 'approx. 1/8' in the summary and 'approximately 1/3' at eq. (14); its own
    # definition (single Pitman arm length over half the track, ~0.1 m / 0.78 m) gives ~1/8.
    ParamSpec("P", 0.125, "1", "Pitman-arm ratio, US 4,788,645 eq. (14), in [0, 1)"),
    ParamSpec("B", 2.7, "m", "wheel base, US 4,788,645 eq. (14)"),
    ParamSpec("T_F", 1.55, "m", "nominal front track, US 4,788,645 eq. (14)"),
    ParamSpec("T_R", 1.55, "m", "rear track (sensor_axle = rear), US 4,788,645 eq. (8)"),
    ParamSpec("a", 1.0e-4, "s2/m2", "velocity coefficient of eq. (8): dtheta_w = dD / (T (1 + a V^2)); initial value when refined"),
    ParamSpec("T_C", 20000.0, "rad.m2/s2", "filter constant of the refinement of a, US 4,788,645 eq. (13): a <- a + ERROR / T_C (one clipped ERROR moves a by M/T_C = 2.6e-6, ~3 % of a typical a: compass offsets across a turn carry degrees of noise)"),
    ParamSpec("D_N", 4500.0, "m", "nominal distance constant of the heading filter, US 4,734,863 FIG. 8D/8G (tuned on simulated drives, docs/tuning.md)"),
    ParamSpec("dpp_left", 0.02, "m", "distance per pulse of the left wheel counter"),
    ParamSpec("dpp_right", 0.02, "m", "distance per pulse of the right wheel counter"),
    ParamSpec("counter_modulus", 65536.0, "1", "wheel pulse counters wrap at this value"),
    # --- compass, US 4,734,863 FIG. 8A / 8C ---------------------------------------------
    ParamSpec("variation_deg", 0.0, "deg", "magnetic variation V, east positive (FIG. 8A block 5)"),
    ParamSpec("X0", 0.0, "compass", "compass x offset (FIG. 8A block 2)"),
    ParamSpec("Y0", 0.0, "compass", "compass y offset (FIG. 8A block 2)"),
    ParamSpec("rotation_deg", 0.0, "deg", "compass mounting rotation R (FIG. 8A block 5)"),
    ParamSpec("field_magnitude", 0.0, "compass",
              "expected horizontal field magnitude B_E (FIG. 8C); <= 0 means learned on the drive per heading "
              "(claim 13): a distance-weighted mean of |B| in 12 heading bins, excluding standstill, disturbed "
              "samples and samples beyond field_learn_gate, forgetting over field_memory_m (jaxmodel.compass); "
              "with filter_field_sigma > 0, |B| also measures the compass's grade and roll errors against the "
              "drive's regression of ln|B| on the heading's harmonics without its first harmonic once the headings "
              "cover the circle, before that against B_E given (else the drive's mean); given, the roll error is "
              "remembered over kilometres (jaxmodel.field_tilt, offset_filter.ROLL_M)"),
    ParamSpec("deviation_deg", (0.0,) * DEVIATION_TABLE_SIZE, "deg",
              "compass deviation table (FIG. 8A block 4), 36 entries at raw headings 0, 10, ..., 350 deg, "
              "interpolated periodically"),
    # --- refinement of a, US 4,788,645 eq. (9)-(13) -------------------------------------
    ParamSpec("refine_M_deg", 3.0, "deg", "clip M of ERROR, eq. (12)"),
    ParamSpec("refine_turn_min_deg", 45.0, "deg", "gate (1): minimum turn for refining a"),
    ParamSpec("refine_speed_min", 6.7056, "m/s", "gate (2): minimum speed during the turn (15 mph)"),
    ParamSpec("refine_speed_max", 20.1168, "m/s", "gate (2): maximum speed during the turn (45 mph)"),
    ParamSpec("refine_compass_max_error_deg", 50.0, "deg", "gate (3): a compass sample is consistent when E_C is below this (5 % field deviation at the default E_C scale)"),
    ParamSpec("refine_compass_bad_fraction", 0.2, "1", "gate (3): a turn passes when at most this fraction of its compass samples is inconsistent"),
    ParamSpec("refine_smoothing_m", 30.0, "m", "distance over which the compass-minus-wheel offset is averaged before/after a turn"),
    ParamSpec("turn_curvature", 0.01, "1", "|dD/AD| above which the vehicle is turning (about 150 m radius)"),
    ParamSpec("straight_distance_m", 25.0, "m", "straight distance that ends a turn"),
    # --- curvature window, US 4,788,645 (the seed evaluates once per second) --------------
    ParamSpec("curvature_window_m", 1.0, "m", "travelled distance over which dD/AD is evaluated: eq. (14)'s T_E per interval of this many metres (at least odometer.INTERVAL_MIN_PULSES pulses) from the interval's own dD/AD (the seed: once per second), and the distance constant of the exponential window of the curvature output"),
    ParamSpec("curvature_clip", 0.98, "1", "curvature is clipped at this fraction of the geometric maximum of eq. (14)"),
    # --- heading filter, US 4,734,863 FIG. 8C-8G ------------------------------------------
    ParamSpec("compass_error_scale_deg", 1000.0, "deg", "E_C = |B_M - B_E| / B_E x this (FIG. 8C block 5; the seed's 60 deg is for its fluxgate, tuned here, docs/tuning.md)"),
    ParamSpec("compass_error_floor_deg", 1.0, "deg", "floor of E_C: a compass is never better than this"),
    ParamSpec("wheel_error_K", 0.1, "1", "E_WI = |alpha K| (FIG. 8D block 2)"),
    ParamSpec("sdd_T", 6.0, "1", "time weighting T of SDD (FIG. 8E/A block 2)"),
    ParamSpec("heading_error_K", 10.0, "1/rad2", "K of E_h = SDD K (E_W - E_C) (FIG. 8E block 2; set by trial as the seed says, docs/tuning.md)"),
    ParamSpec("K1", 1.0, "1", "F = (E_h + K1)/K1 when the wheels are the worse sensor (FIG. 8E block 4)"),
    ParamSpec("K2", 0.3, "1", "F = K2/(|E_h| + K2) when the compass is the worse sensor (FIG. 8E block 5)"),
    ParamSpec("F_update_distance_m", 10.0, "m", "threshold distance between updates of F (FIG. 8 block 6)"),
    ParamSpec("map_threshold_deg", 10.0, "deg", "map heading replaces the compass when it agrees with the estimate within this (FIG. 8F)"),
    ParamSpec("reliability_scale_deg", 2.0, "deg", "heading_reliability = 1 / (1 + bound / this)"),
    ParamSpec("max_speed", 90.0, "m/s", "plausibility: larger wheel speeds are counter faults and are skipped"),
    ParamSpec("glitch_pulses", 4.0, "1", "plausibility (jaxmodel/plausibility.py): dD may depart from its recent rate by this many pulses"),
    ParamSpec("glitch_dD_rate", 0.5, "m/s", "plausibility: plus this change of the dD rate within a 0.1-s sample (a yaw acceleration: over longer intervals the allowed change grows with the interval, plausibility.course_tolerance)"),
    # --- robust F-DELTA filter (jaxmodel/offset_filter.py; FIG. 8G's filter, fitted in docs/tuning.md) ---
    ParamSpec("filter_offset_psd", 4.127e-08, "rad2/m", "random walk of the wheel heading offset per metre driven (10x the fitted 4.127e-09: held-out seeds and single spurious pulses, docs/tuning.md stop 28)"),
    ParamSpec("filter_rate_psd", 1.206e-15, "rad2/m3", "random walk of the offset's rate per metre (tyre wear, load)"),
    ParamSpec("filter_rate_corr_m", 300.0, "m", "without an absolute heading the offset's rate fades over this distance (not extrapolated through long compass dropouts)"),
    ParamSpec("filter_rate_sigma0", 0.002992, "rad/m", "initial sigma of the offset's rate (left/right tyre mismatch / track)"),
    ParamSpec("filter_sigma0_deg", 11.78, "deg", "initial sigma of F-DELTA when the first compass sample starts the heading"),
    ParamSpec("filter_turn_sigma", 0.1616, "1", "relative sigma of a wheel turn as offset noise: adds (this x alpha)^2 to F-DELTA's variance"),
    ParamSpec("filter_steady_turn_sigma", 0.0349, "1", "relative sigma of a wheel turn as offset noise in the steady F-DELTA (no rate state), which gives the heading while the rate filter's rate is insignificant"),
    ParamSpec("filter_rate_significance", 2.891, "1", "the heading shows the rate filter's offset while its rate exceeds this many of its sigmas (the wheels drift: a tyre mismatch not yet calibrated)"),
    ParamSpec("filter_follow_hold_m", 20000.0, "m", "the steady F-DELTA takes the rate filter's state for this many metres after the calibration captured a drift or moved the ratio within this of a large drift (with the calibration off: after a large drift); what the calibration has not yet taken out; 0: off"),
    ParamSpec("filter_follow_show_rate", 1e-4, "rad/m", "the heading shows the rate filter's offset only while its significant rate is larger than about this (smooth step, 1/2 here; slow compass errors on hills fake 50-110 µrad/m for kilometres, a 0.1 % tyre mismatch turns the wheels ~700; 0: any significant rate)"),
    ParamSpec("filter_follow_hold_rate", 5e-4, "rad/m", "a significant rate larger than this is a large drift: captured into the left/right ratio (with the calibration off: starts filter_follow_hold_m); a tyre mismatch of 0.1 % turns the wheels ~600 µrad/m on a 1.6-m track, dip errors on grades look like 100 (docs/tuning.md, stop 52)"),
    ParamSpec("filter_scale_sigma0", 0.0, "1", "initial sigma of the wheel turn's relative scale error; 0 (default) switches the scale state off, 0.05-0.15 for a vehicle whose track, dpp or a were not identified"),
    ParamSpec("filter_scale_psd", 0.0, "1/rad", "random walk of the wheel turn's scale error per radian turned (load, tyre wear)"),
    ParamSpec("filter_scale_speed_ref", 0.0, "m/s", "0: the scale state k is the wheel turn's relative error at every speed; > 0: its error at this speed, scaling as V^2 (eq. (8)'s 1 + a V^2 with a wrong a)"),
    ParamSpec("filter_compass_sigma_deg", 2.918, "deg", "white compass noise sigma in the F-DELTA filter (plus filter_ec_weight x E_C)"),
    ParamSpec("filter_compass_corr_m", 0.1148, "m", "white compass noise counted once per this many metres (no gain while standing)"),
    ParamSpec("filter_ec_weight", 0.07855, "1", "weight of the compass error bound E_C (FIG. 8C) in the filter's compass sigma"),
    ParamSpec("filter_compass_lag_s", 0.5, "s", "the filter's compass sigma grows by this x the wheels' turn rate (a filtered magnetometer lags in turns; docs/tuning.md stop 29)"),
    ParamSpec("filter_gm_m", 179.4, "m", "correlation distance of the compass's coloured error (anomalies, dip on hills)"),
    ParamSpec("filter_gm_sigma_deg", 1.0, "deg", "stationary sigma of the compass's coloured error"),
    ParamSpec("filter_tilt_sigma_deg", 3.27, "deg", "stationary sigma of the tilt error: the heading error of a level-mounted compass heading magnetic east or west on a grade (tan(dip) x pitch; nothing heading north or south)"),
    ParamSpec("filter_tilt_m", 593.0, "m", "correlation distance of the tilt error (road grades)"),
    ParamSpec("filter_field_sigma", 0.07, "1", "noise of ln(|B| / B_E) per compass measurement, |B| read as the compass's grade and roll errors against B_E given or learned (jaxmodel.field_tilt; 0 = not read; docs/tuning.md stops 59-60)"),
    ParamSpec("filter_check_m", 2.53, "m", "distance over which DELTA's agreement with the wheels is averaged (disturbance detection)"),
    ParamSpec("filter_check_sigma_deg", 1.389, "deg", "expected spread of that average on a clean compass"),
    ParamSpec("filter_gate_sigma", 0.4081, "1", "soft gate: compass variance inflated by 1 + (disturbance/sigma)^2 / this^2, and beyond this many sigmas of innovation"),
    ParamSpec("filter_reacquire_drift_deg", 2.0, "deg", "re-acquisition after filter_reacquire_m only when the rate filter's rate turns the offset by more than this over that distance (the wheels' drift explains the disagreement: a lock-out)"),
    ParamSpec("filter_reacquire_step_m", 15000.0, "m", "otherwise a compass rejected this many metres in a row restarts F-DELTA (a step in the wheel heading; a shifted hard iron on a highway, without turns to learn it from, is rejected for as long)"),
    ParamSpec("filter_reacquire_large_deg", 60.0, "deg", "a compass that disagrees with F-DELTA by more than this (averaged over filter_check_m) says the heading itself is wrong (a drive started in a garage)"),
    ParamSpec("filter_reacquire_lost_m", 100.0, "m", "such a compass restarts F-DELTA after this many metres driven with it that far off (counted from a jump beyond filter_reacquire_large_deg, or from when the running disagreement passed it; held while the compass stays rejected); a filter anchored for filter_reacquire_m of compass: after half of filter_reacquire_m at least"),
    ParamSpec("filter_reacquire_lost_steady_m", 10.0, "m", "and after this many when that disagreement is steady (wanders less than 15 deg RMS over 10 m, 3 deg once anchored for filter_reacquire_m: a heading started wrong in a garage, not an anomaly); while moving, these metres count at no less than 4 m/s"),
    ParamSpec("filter_reject_harden_m", 300.0, "m", "a compass rejected R metres in a row has its variance multiplied by 1 + (R / this)^2 unless the rate filter's rate explains the disagreement (a persistent compass error does not creep in)"),
    ParamSpec("filter_reacquire_m", 1000.0, "m", "a compass rejected this many metres in a row restarts F-DELTA from it (re-acquisition after a lock-out)"),
    ParamSpec("field_learn_gate", 0.08, "1", "B_E per heading learns only from |B| within this (relative) of the current B_E"),
    ParamSpec("field_memory_m", 5000.0, "m", "distance over which the learned B_E per heading forgets (hard-iron changes)"),
    # --- online hard-iron estimate (Config.hard_iron, jaxmodel/hard_iron.py; our extension of FIG. 8A block 2)
    ParamSpec("hard_iron_memory_m", 10000.0, "m", "Config.hard_iron: distance over which the circle fit of the field forgets (a changed offset is followed within about this)"),
    ParamSpec("hard_iron_min_turn_deg", 120.0, "deg", "Config.hard_iron: a fit is accepted once its field samples spread as much as headings covering an arc of this width"),
    ParamSpec("hard_iron_min_distance_m", 30.0, "m", "Config.hard_iron: and once the fit holds this many metres of samples"),
    ParamSpec("hard_iron_gate", 0.15, "1", "Config.hard_iron: Cauchy weight 1/(1 + (e/(this r))^2) of a sample e off the accepted circle of radius r (anomalies)"),
    ParamSpec("hard_iron_restart_fraction", 0.25, "1", "Config.hard_iron: the first accepted fit restarts the heading from the corrected compass when it moves X0/Y0 by more than this x r"),
    # --- left/right dpp calibration, EP 0619873 (jaxmodel/calibration.py) -----------------
    ParamSpec("cal_check_distance_m", 20.0, "m", "EP 0619873 claims 2-3: the count ratio is checked over windows of this distance"),
    ParamSpec("cal_ratio_bound", 0.01, "1", "EP 0619873 claims 2-3: bound on a window's |dD/AD| (current dpp) for the stretch to go on"),
    ParamSpec("cal_stretch_distance_m", 200.0, "m", "EP 0619873 claims 12-13: bounded distance that yields one correction ratio"),
    ParamSpec("cal_compass_tolerance_deg", 1.0, "deg", "EP 0619873 claims 6-9: intensity exp(-0.5 (compass heading change / this)^2)"),
    ParamSpec("cal_no_compass_weight", 0.001, "1", "EP 0619873 claim 5: intensity of a stretch the compass cannot check (without it a gentle curve reads as a tyre mismatch; not 0, so that its logit stays finite when fitted)"),
    ParamSpec("cal_sanity_bound", 0.005, "1", "EP 0619873 claims 10-11: sanity intensity 1/(1 + ((k_s/filtered ratio - 1)/this)^2)"),
    ParamSpec("cal_steady_bound", 0.003, "1", "EP 0619873 claims 2-3 (Config.robust): a window's dD/AD may differ from the previous window's by this for the stretch to go on"),
    ParamSpec("cal_sanity_boost", 20.0, "1", "EP 0619873 claim 11: at most this much more intensity when consistent stretches disagree with the filtered ratio"),
    ParamSpec("cal_prior_weight", 0.1, "1", "EP 0619873 claim 13: weight of the parameter ratio in the filtered ratio, in stretches"),
    ParamSpec("cal_filter_stretches", 100.0, "1", "EP 0619873 claim 13: memory of the filtered correction ratio, in stretches"),
    ParamSpec("cal_stretch_sigma", 1.5e-4, "1", "prior spread of one stretch's correction ratio (pooled with the observed spread)"),
    ParamSpec("cal_significance", 5.0, "1", "significance z: applied k = k0 + d / (1 + (z^2 var_mean / d^2)^2), d = filtered ratio - k0"),
    ParamSpec("cal_max_correction", 0.03, "1", "EP 0619873: the ratio stays within this (relative) of dpp_right/dpp_left"),
    # --- Kalman mode, US 4,680,715 (jaxmodel/kalman.py) -----------------------------------
    ParamSpec("kf_gm_tau_s", 660.0, "s", "US 4,680,715: time constant of the Gauss-Markov course error dth1 (the compass's colored error)"),
    ParamSpec("kf_gm_m", 180.0, "m", "correlation distance of dth1 (magnetic anomalies are places: the compass's colored error also decorrelates over the road driven; 1e9: time alone, as the seed)"),
    ParamSpec("kf_gm_sigma_deg", 0.7, "deg", "US 4,680,715: stationary sigma of dth1 (anomalies, dip errors on hills)"),
    ParamSpec("kf_heading_sigma0_deg", 3.0, "deg", "US 4,680,715: initial sigma of the drift angle dth2 (heading started from one compass sample)"),
    ParamSpec("kf_ramp_sigma0_deg_per_min", 0.02, "deg/min", "US 4,680,715: initial sigma of the ramp pitch eps"),
    ParamSpec("kf_ramp_psd", 2.4e-13, "rad2/s3", "US 4,680,715: PSD of the white noise driving the ramp pitch eps (random ramp)"),
    ParamSpec("kf_drift_psd", 2.3e-11, "rad2/s", "random-walk PSD (per second) of the drift angle dth2, the wheel course error"),
    ParamSpec("kf_drift_per_m", 1.0e-8, "rad2/m", "random-walk intensity of the drift angle dth2 per metre driven (wheel slip)"),
    ParamSpec("kf_rate_sigma0", 0.0, "rad/m", "initial sigma of the wheel course's drift per metre beta (a tyre mismatch the parameters do not know, / track); 0: beta starts known, released while the rate filter finds a significant drift"),
    ParamSpec("kf_rate_psd", 0.0, "rad2/m3", "random walk of beta per metre (tyre wear, load); 0: none"),
    ParamSpec("kf_turn_sigma", 1.2e-4, "1", "relative sigma of the wheel course change (track/velocity-term error): adds (this x alpha)^2 to dth2"),
    ParamSpec("kf_white_sigma_deg", 0.35, "deg", "US 4,680,715: sigma of the white course error dth3"),
    ParamSpec("kf_compass_sigma_deg", 4.3, "deg", "white compass course noise sigma (plus kf_compass_ec_weight x E_C)"),
    ParamSpec("kf_map_sigma_deg", 1.0, "deg", "white sigma of the map (street) course where the map-heading selector uses it (FIG. 8F)"),
    ParamSpec("kf_compass_ec_weight", 1.0, "1", "weight of the compass error bound E_C (FIG. 8C) in the compass measurement sigma"),
    ParamSpec("kf_compass_corr_m", 2.2, "m", "white compass noise counted once per this many metres: R x max(1, this/|AD|) (no gain while standing)"),
    ParamSpec("kf_fix_sigma_m", 2.2, "m", "US 4,680,715: sigma of the white part of the fix errors, per axis (the seed's model when kf_fix_gm_sigma_m = 0)"),
    ParamSpec("kf_fix_gm_sigma_m", 1.2, "m", "stationary sigma of the colored (first-order Gauss-Markov) part of the fix errors, per axis; 0 = white fixes as in the seed"),
    ParamSpec("kf_fix_gm_tau_s", 28.0, "s", "time constant of the colored part of the fix error (multipath, atmosphere)"),
    ParamSpec("kf_pos_sigma0_m", 10.0, "m", "initial sigma of the north/east position errors"),
    ParamSpec("kf_speed_sigma", 1.7e-5, "1", "relative distance-scale noise of the corrected speed CV (along-track position noise)"),
    ParamSpec("kf_pos_psd", 8.5e-7, "m2/s", "random-walk PSD of the north/east position errors"),
    ParamSpec("kf_gate_sigma", 4.0, "1", "soft innovation gate (Mahalanobis sigmas) beyond which R is inflated; <= 0 disables"),
    ParamSpec("kf_max_accel", 15.0, "m/s2", "US 4,680,715 plausibility: larger speed changes are not used (speed slews instead)"),
    ParamSpec("kf_max_yaw_rate_deg_s", 120.0, "deg/s", "US 4,680,715 plausibility: larger wheel course rates are taken as errors"),
    ParamSpec("kf_speed_factor", 1.0, "1", "US 4,680,715 DF(V): corrected speed CV = this x V_M (known scale error; 1 = none)"),
)
# fmt: on

PARAMETER_SPECS: dict[str, ParamSpec] = {p.key: p for p in PARAMETER_TABLE}
PARAMETER_KEYS: tuple[str, ...] = tuple(p.key for p in PARAMETER_TABLE)

Params = NamedTuple("Params", [(k, jnp.ndarray) for k in PARAMETER_KEYS])  # type: ignore[misc]
Params.__doc__ = "Estimator parameters, float64 arrays (scalars, or shape (36,) for deviation_deg). See PARAMETER_TABLE."


class ParameterError(ValueError):
    """A parameter file or mapping is invalid; the message names the key."""


MAX_MAGNITUDE = 1.0e12
"""No parameter is this large in any unit the table uses: a larger value is a typo or an overflow
(B = 1e308 would turn eq. (14) into inf).  ``counter_modulus`` may go up to 2**53 (exact in float64)."""
MAX_COUNTER_MODULUS = 2.0**53
MAX_VEHICLE_LENGTH_M = 50.0
"""Wheel base and tracks above this are not a land vehicle's (and make eq. (14) meaningless)."""
MAX_DPP_M = 10.0
"""Distance per pulse above this is not a wheel pulse sensor's."""


def _to_number(key: str, value: Any) -> Any:
    if key == "sensor_axle":
        if isinstance(value, str) and value in ("front", "rear"):
            return 1.0 if value == "front" else 0.0
        if value in (1, 1.0, True):
            return 1.0
        if value in (0, 0.0, False):
            return 0.0
        raise ParameterError(f"parameter 'sensor_axle' must be 'front' or 'rear', got {value!r}")
    if key == "deviation_deg":
        if isinstance(value, (str, bytes, Mapping)):
            raise ParameterError(f"parameter 'deviation_deg' must be a list of {DEVIATION_TABLE_SIZE} numbers, "
                                 f"got {type(value).__name__}")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ParameterError(f"parameter 'deviation_deg' must be a list of {DEVIATION_TABLE_SIZE} numbers, "
                                 f"got {value!r:.80}") from None
        if arr.shape != (DEVIATION_TABLE_SIZE,):
            raise ParameterError(f"parameter 'deviation_deg' must be a list of {DEVIATION_TABLE_SIZE} numbers, got shape {arr.shape}")
        return arr
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ParameterError(f"parameter {key!r} must be a number, got {value!r:.80}")
    if isinstance(value, int) and abs(value) > 2**1023:
        raise ParameterError(f"parameter {key!r} is absurdly large ({str(value)[:20]}...)")
    number = float(value)
    if key == "counter_modulus" and math.isfinite(number) and number != round(number):
        raise ParameterError(f"parameter 'counter_modulus' must be a whole number of counts, got {value!r}")
    return number


def make_params(values: Mapping[str, Any] | None = None, **overrides: Any) -> Params:
    """Params from defaults, updated by ``values`` and ``overrides`` (JSON-style values)."""
    if not jax.config.jax_enable_x64:
        raise ParameterError("odocompass needs 64-bit JAX: call jax.config.update('jax_enable_x64', True) "
                             "or work inside `with jax.enable_x64(True):`")
    merged: dict[str, Any] = {p.key: p.default for p in PARAMETER_TABLE}
    for source in (values or {}, overrides):
        for key, value in source.items():
            if key not in PARAMETER_SPECS:
                raise ParameterError(f"unknown parameter key {key!r}")
            merged[key] = value
    return Params(**{k: jnp.asarray(_to_number(k, v), dtype=jnp.float64) for k, v in merged.items()})


POSITIVE_KEYS = (
    "B", "T_F", "T_R", "dpp_left", "dpp_right", "counter_modulus", "T_C", "D_N", "curvature_window_m", "sdd_T", "K1",
    "K2", "F_update_distance_m", "max_speed", "refine_smoothing_m", "straight_distance_m", "reliability_scale_deg",
    "turn_curvature", "compass_error_scale_deg", "refine_compass_max_error_deg",
    "cal_check_distance_m", "cal_ratio_bound", "cal_stretch_distance_m", "cal_compass_tolerance_deg",
    "cal_sanity_bound", "cal_steady_bound", "cal_sanity_boost", "cal_filter_stretches", "cal_stretch_sigma", "cal_max_correction",
    "kf_gm_tau_s", "kf_gm_m", "kf_fix_gm_tau_s", "kf_fix_sigma_m", "kf_heading_sigma0_deg", "kf_pos_sigma0_m", "kf_max_accel",
    "kf_max_yaw_rate_deg_s", "kf_speed_factor", "filter_gm_m", "filter_tilt_m", "filter_sigma0_deg", "filter_compass_sigma_deg", "filter_compass_corr_m", "filter_check_m", "filter_check_sigma_deg", "filter_gate_sigma",
    "filter_reacquire_m", "filter_rate_corr_m", "filter_reacquire_step_m", "filter_reject_harden_m", "filter_reacquire_large_deg", "filter_reacquire_lost_m", "filter_reacquire_lost_steady_m", "field_learn_gate", "field_memory_m", "hard_iron_memory_m", "hard_iron_min_turn_deg", "hard_iron_gate")
"""Time constants, lengths, scales and divisors: zero or negative values make the equations meaningless."""
NON_NEGATIVE_KEYS = (
    "a", "refine_M_deg", "refine_turn_min_deg", "refine_speed_min", "compass_error_floor_deg",
    "wheel_error_K", "heading_error_K", "map_threshold_deg", "cal_prior_weight", "cal_significance",
    "kf_gm_sigma_deg", "kf_ramp_sigma0_deg_per_min", "kf_ramp_psd", "kf_drift_psd", "kf_drift_per_m", "kf_rate_sigma0", "kf_rate_psd", "kf_turn_sigma",
    "kf_white_sigma_deg", "kf_compass_sigma_deg", "kf_map_sigma_deg", "kf_compass_ec_weight", "kf_compass_corr_m",
    "kf_fix_gm_sigma_m", "kf_speed_sigma", "kf_pos_psd", "glitch_pulses", "glitch_dD_rate", "filter_offset_psd",
    "filter_rate_psd", "filter_rate_sigma0", "filter_gm_sigma_deg", "filter_tilt_sigma_deg", "filter_turn_sigma", "filter_ec_weight",
    "filter_compass_lag_s", "filter_field_sigma",
    "filter_scale_sigma0", "filter_scale_psd", "filter_scale_speed_ref", "filter_steady_turn_sigma", "filter_rate_significance", "filter_follow_hold_m", "filter_follow_hold_rate",
    "filter_follow_show_rate", "filter_reacquire_drift_deg",
    "hard_iron_min_distance_m", "hard_iron_restart_fraction")
"""Sigmas, noise intensities, gains and thresholds: zero switches the effect off."""
FRACTION_KEYS = ("refine_compass_bad_fraction", "cal_no_compass_weight")
"""Fractions and weights in [0, 1]."""


def validate_params(params: Params) -> None:
    """Raise ParameterError naming every physically invalid parameter (used before estimation and by the FMU)."""
    problems = []

    def val(k):
        return np.asarray(getattr(params, k), dtype=np.float64)

    for k in PARAMETER_KEYS:
        if not np.all(np.isfinite(val(k))):
            problems.append(f"{k} is not finite")
    if not 0.0 <= float(val("P")) < 1.0:
        problems.append(f"P={float(val('P'))} outside [0, 1)")
    for k in POSITIVE_KEYS:
        if not float(val(k)) > 0.0:
            problems.append(f"{k}={float(val(k))} must be positive")
    for k in NON_NEGATIVE_KEYS:
        if not float(val(k)) >= 0.0:
            problems.append(f"{k}={float(val(k))} must not be negative")
    for k in FRACTION_KEYS:
        if not 0.0 <= float(val(k)) <= 1.0:
            problems.append(f"{k}={float(val(k))} must be in [0, 1]")
    if not float(val("refine_speed_min")) <= float(val("refine_speed_max")):
        problems.append(f"refine_speed_min={float(val('refine_speed_min'))} above "
                        f"refine_speed_max={float(val('refine_speed_max'))}")
    if float(val("sensor_axle")) not in (0.0, 1.0):
        problems.append(f"sensor_axle={float(val('sensor_axle'))} must be front (1) or rear (0)")
    if not 0.0 < float(val("curvature_clip")) < 1.0:
        problems.append(f"curvature_clip={float(val('curvature_clip'))} must be in (0, 1)")
    for k in PARAMETER_KEYS:
        v = val(k)
        limit = MAX_COUNTER_MODULUS if k == "counter_modulus" else MAX_MAGNITUDE
        if np.all(np.isfinite(v)) and np.any(np.abs(v) > limit):
            problems.append(f"{k}={float(np.max(np.abs(v))):g} is absurdly large (|value| above {limit:g})")
    for k, limit, what in (("B", MAX_VEHICLE_LENGTH_M, "m"), ("T_F", MAX_VEHICLE_LENGTH_M, "m"),
                           ("T_R", MAX_VEHICLE_LENGTH_M, "m"), ("dpp_left", MAX_DPP_M, "m"),
                           ("dpp_right", MAX_DPP_M, "m")):
        if k in PARAMETER_SPECS and MAX_MAGNITUDE >= float(val(k)) > limit:
            problems.append(f"{k}={float(val(k)):g} {what} is beyond any land vehicle (at most {limit:g} {what})")
    if problems:
        raise ParameterError("invalid parameters: " + "; ".join(problems))


def params_to_dict(params: Params) -> dict[str, Any]:
    """JSON-ready dict of a (single, unbatched) Params."""
    out: dict[str, Any] = {}
    for k in PARAMETER_KEYS:
        v = np.asarray(getattr(params, k), dtype=np.float64)
        if k == "sensor_axle":
            out[k] = "front" if float(v) >= 0.5 else "rear"
        elif k == "deviation_deg":
            out[k] = [float(x) for x in v]
        else:
            out[k] = float(v)
    return out


def _no_duplicates(path: Path):
    def hook(pairs):
        seen = set()
        for k, _ in pairs:
            if k in seen:
                raise ParameterError(f"{path}: duplicate key {k!r} (a JSON object may name a key once)")
            seen.add(k)
        return dict(pairs)

    return hook


def _refuse_constant(path: Path):
    def hook(name):
        raise ParameterError(f"{path}: {name} is not a number in JSON (parameters must be finite)")

    return hook


TRUTH_FILE_KEYS = ("params", "scenario", "seed", "truth_csv")
"""A simulator truth file (``DRIVE.truth.json``) holds the true parameters under ``params``."""

VEHICLE_KEYS = ("P", "B", "T_F", "T_R", "a", "dpp_left", "dpp_right")
"""The vehicle's own wheel geometry and scale: where none is given, the nominal vehicle is assumed."""
UNIDENTIFIED_VEHICLE = {"filter_scale_sigma0": 0.15, "filter_scale_psd": 1e-9, "filter_tilt_sigma_deg": 2.0,
                        "filter_reject_harden_m": 699.1}
"""The offset filter's turn-scale state for a vehicle whose parameters nobody gave (docs/tuning.md:
nominal parameters on the matrix 20.2 -> 3.7 deg on the tuning seeds, 16.0 -> 2.2 on the evaluation
seeds; off by default, since with the vehicle's own parameters it costs 5-11 %).  Its prior sigma 0.15, not 0.05
(stop 80, nominal parameters, the matrix's 15 conditions with a compass: tuning seeds 101-103 1.886 -> 1.238 deg,
58 -> 99 of 180 met; held-out 104-106 1.310 -> 1.293 deg; the independent simulator's diagnosis drives, whose dpp
is up to 2.4x the nominal, 10.35 -> 7.39 deg): a vehicle nobody gave is not within a few per cent of the nominal.  Switched on wherever the file does not give the
wheel turn's scale (``for_unidentified_vehicle``, stop 81); the dpp themselves are then found from the drive's compass
where the file gives neither (identification/wheel_scales.py).
With it on, the tilt state's sigma stays at 2 deg (stop 25, nominal parameters: tuning seeds 101-103 2.41 -> 2.25 deg, held-out
104-106 1.79 -> 1.71 deg against the default 3 deg), as the scale state explains part of what the tilt did.
The rejected compass is hardened against over 699 m as before stop 26, not the default 300 m (nominal parameters:
101-103 2.354 -> 2.250 deg, 104-106 1.729 -> 1.714 deg): wheels with another vehicle's parameters disagree with
a clean compass for long, and the compass is then the one to keep."""
UNKNOWN_VELOCITY_COEFFICIENT = {"filter_scale_sigma0": 0.008, "filter_scale_speed_ref": 10.0}
"""The turn-scale state for a vehicle whose wheel turn's scale is given (a dpp and the track) but not its velocity
coefficient a: eq. (8)'s 1 + a V^2 with a wrong a puts a relative error of about (a_0 - a) V^2 on every turn, so the
state k is that error at filter_scale_speed_ref and scales as V^2 (``offset_filter.predict``).  Stop 83, the vehicle's
own file less a (nominal 1e-4), default mode, geometric mean RMSE after the first minute: another simulator's
vehicles (a 3e-5 to 2.4e-4), diagnosis seeds 1-4/28-33, 40 drives, 1.319 -> 1.169 deg (prior sigma 0.004 / 0.015:
1.171 / 1.196; the patent's online refinement of a, T_C 500-2000 m, 1.35-1.33; the true a 1.107); the matrix, 15
conditions with a compass, tuning seeds 101-103 1.026 -> 0.884, held-out 104-106 1.244 -> 0.850 (docs/tuning.md)."""
_TURN_SCALE_KEYS = ("filter_scale_sigma0", "filter_scale_psd", "filter_scale_speed_ref")
DPP_KEYS = ("dpp_left", "dpp_right")
"""The wheels' distance per pulse: with the sensor axle's track they give the wheel turn's scale."""


def for_unidentified_vehicle(params: Params, given_keys) -> tuple[Params, bool]:
    """(params, True) with UNIDENTIFIED_VEHICLE switched on (except any key of it that ``given_keys`` set) when
    ``given_keys`` (the keys a parameter file set) do not give the wheel turn's scale (a dpp and the sensor axle's
    track: T_F front, T_R rear; the turn's scale is dpp / T_E, US 4,788,645 eq. (8)) and set no turn-scale key
    themselves; else (params, False).  Since stop 81 a file with the track but no dpp, or a dpp but no track,
    counts as not giving it (independent simulator, diagnosis drives: no track 4.19 -> 1.50 deg with the state; no
    dpp, found from the compass, 2.59 -> 1.81; docs/tuning.md).  A file that gives the scale but not eq. (8)'s a
    gets the speed-scaled state of UNKNOWN_VELOCITY_COEFFICIENT instead (stop 83), still (params, False): the
    vehicle is given."""
    given = set(given_keys)
    track = "T_F" if float(params.sensor_axle) > 0.5 else "T_R"  # the track of the axle that carries the sensors
    scale_given = bool(given & set(DPP_KEYS)) and track in given
    if given & set(_TURN_SCALE_KEYS) or (scale_given and "a" in given):
        return params, False
    if scale_given:
        return _switched_on(params, UNKNOWN_VELOCITY_COEFFICIENT, given), False
    return _switched_on(params, UNIDENTIFIED_VEHICLE, given), True


def _switched_on(params: Params, settings, given) -> Params:
    """``params`` with ``settings`` (key -> value) but for the keys the file gave."""
    return params._replace(**{k: jnp.asarray(v, jnp.float64) for k, v in settings.items() if k not in given})


def load_params(path: str | Path) -> tuple[Params, dict[str, Any]]:
    """Read a parameter JSON file. Returns (params, extra) where extra holds the optional ``report``
    and ``keys``, the parameter keys the file sets (the others are the defaults).

    Accepts a flat parameter file (SPEC §3, optionally with a ``report`` object) and the truth
    file ``simulate`` writes beside a drive (its ``params`` object).  Raises ParameterError with
    the file name and the offending key: unreadable or non-UTF-8 file, invalid JSON, duplicate
    keys, NaN/Infinity, unknown keys, wrong types, non-integer counter_modulus.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ParameterError(f"{path}: parameter file not found") from None
    except IsADirectoryError:
        raise ParameterError(f"{path}: is a folder, not a parameter file") from None
    except OSError as exc:
        raise ParameterError(f"{path}: cannot read the parameter file: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{path}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
                             f"save the parameter file as UTF-8 JSON") from None
    try:
        raw = json.loads(text, object_pairs_hook=_no_duplicates(path), parse_constant=_refuse_constant(path))
    except json.JSONDecodeError as exc:
        raise ParameterError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None
    except RecursionError:
        raise ParameterError(f"{path}: not valid JSON (nested too deeply)") from None
    if not isinstance(raw, dict):
        raise ParameterError(f"{path}: expected a JSON object of parameter keys")
    if all(k in raw for k in TRUTH_FILE_KEYS) and isinstance(raw["params"], dict):
        raw = dict(raw["params"])  # simulate's truth file: its true parameters
    extra = {"report": raw.pop("report")} if "report" in raw else {}
    extra["keys"] = tuple(raw)
    try:
        params = make_params(raw)
    except ParameterError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    except (OverflowError, ValueError, TypeError) as exc:
        raise ParameterError(f"{path}: {' '.join(str(exc).split())}") from None
    return params, extra


def save_params(path: str | Path, params: Params, report: Mapping[str, Any] | None = None) -> None:
    """Write a flat parameter JSON file (plus an optional ``report`` object), atomically: a
    temporary file beside the target replaces it only once completely written."""
    import os
    import tempfile

    path = Path(path)
    data = params_to_dict(params)
    if report is not None:
        data["report"] = report
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"  # before any file is touched
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp.json", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def deg(x):
    """Degrees to radians (a name that reads well next to the *_deg keys)."""
    return x * (math.pi / 180.0)


def field_magnitude_given(params):
    """Whether B_E was given (``field_magnitude`` > 0, bool); else it is learned on the drive per heading (claim 13).
    The estimator's one reader of the parameter's "<= 0 means learned" convention (the simulator's is
    ``identification.sensors.horizontal_field``)."""
    return params.field_magnitude > 0.0
