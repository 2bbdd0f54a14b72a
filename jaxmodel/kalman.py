"""Kalman-filter mode, US 4,680,715 (``Config(mode="kalman")``).

An error-state Kalman filter with eight states and small fixed-size jnp matrices:

    x = [dth1, dth2, eps, dN, dE, bN, bE, beta]

* Course-error model of claim 1: dth = dth1 + dth2 + dth3, with dth1 a first-order
  Gauss-Markov process (time constant kf_gm_tau_s and correlation distance kf_gm_m, Phi = exp(-dt/tau - |s|/L),
  stationary sigma kf_gm_sigma_deg; the seed's is in time alone, but an anomaly is a place), dth2 a
  drift angle with an unknown start value whose pitch eps is a random ramp (eps a random walk,
  PSD kf_ramp_psd; dth2 also gets random-walk noise per second kf_drift_psd, per metre
  kf_drift_per_m and per turned radian kf_turn_sigma), and dth3 Gaussian white noise
  (kf_white_sigma_deg, not a state).
* The wheels' drift per metre beta (rad/m): dth2 also grows by beta s over a sample of s metres.  The seed's
  ramp is per second; a left/right tyre mismatch turns the wheel course per metre (mismatch / track), 0.2-0.6
  deg per metre for 0.5-1.5 % before the calibration (EP 0619873) has found it.  Without beta the filter held
  the compass off on every such drive of the scenario matrix (50-90 deg RMSE, stop 48).  beta starts known
  (kf_rate_sigma0 = 0: the parameters' ratio is taken as true) and is released while the complementary filter's
  rate filter finds a large, significant drift, or a significant one the course has run far from the compass
  with (``released_rate_variance``; its variance then at least that rate's square and variance); a new
  calibration shifts it by the change of the wheel course's rate (``rate_change``).
* North/east position errors dN, dE of the position computer, fed by the course error of the
  dead-reckoned course: dN' = dN - s sin(th) dth2, dE' = dE + s cos(th) dth2 (s: corrected
  distance of the sample).
* North/east errors bN, bE of the position fixes: first-order Gauss-Markov (kf_fix_gm_tau_s,
  kf_fix_gm_sigma_m), on top of white noise (kf_fix_sigma_m).  Claim 1 takes the fix errors as
  white only; a GNSS receiver's are not (multipath, atmosphere: correlated over tens of
  seconds), and a filter that takes a 30-s-correlated error for white reads it as a course
  error.  kf_fix_gm_sigma_m = 0 is the seed's white model.

Our reading of the seed for an odometer + compass system.  The seed's course reference is a
single course sensor; here two course signals are combined, so the model describes the error
of their difference, z = wrap(H_W - H_C) = dth1 + dth2 + dth3 (H = [1, 1, 0, 0, 0, 0, 0]), and each
component is given to the sensor whose physics it describes:
* the course that is dead-reckoned is the wheel heading H_W (the odometer integrates, so its
  error is the drift with a random ramp, dth2);
* the compass's error is bounded and correlated in time and over the road (magnetic anomalies, dip errors on
  hills: the Gauss-Markov dth1) plus white noise (dth3, with the wheel pulse quantization); what the grade and
  the roll turn it by at each heading, as the robust F-DELTA estimated it (field_tilt), is taken out of H_C
  before (model._kalman_compass, step 2's deterministic corrections);
* the corrected course is C_th = H_W - dth2^, and only dth2 drives the position errors.
Tried on simulated drives: putting dth1 into the dead-reckoned course as well (C_th = H_W -
dth1^ - dth2^) tunes to a vanishing dth1 and is no better; this split uses all three parts.
The position fixes (fix_east_m, fix_north_m when fix_valid) measure dN - bN, dE - bE.

Steps of claim 1, per sample:
1. Plausibility of the speed V_M = AD/dt: implausible pulse counts (the odometer's own check)
   or a speed change beyond kf_max_accel (plus one pulse of quantization each way) are not
   used; the speed then slews towards the measurement at kf_max_accel (no lock-out).
   Plausibility of the course: a wheel course change beyond kf_max_yaw_rate_deg_s (plus four
   pulses of quantization) is treated as an error (added to the drift estimate dth2, so the
   corrected course ignores it); the compass course is used only when valid (finite, field
   above the minimum) and is down-weighted by its error bound E_C (FIG. 8C of US 4,734,863)
   and by a soft innovation gate (kf_gate_sigma: R is inflated by d^2/gate^2 beyond the gate,
   never a hard rejection, so no lock-out and the gradient stays defined).
2. Deterministic corrections.  DF(V): the distance is pulses x the calibrated distance per
   pulse (EP 0619873) times kf_speed_factor (a known, empirically derived scale error; 1 = none),
   so DF(V) = (kf_speed_factor - 1) V_M.  DF(th): the known deterministic course corrections,
   i.e. for the wheel course the Ackerman track and velocity term of US 4,788,645 eq. (8)/(14)
   (already in H_W) and for the compass course offsets, deviation table, rotation and variation
   of US 4,734,863 FIG. 8A (already in H_C).
3. Corrected course C_th = H_W - C(th), C(th) = dth2^ (open loop: H_W itself is never
   reset, the model's odometer keeps integrating it).  Position computer: CRN += CV cos(C_th),
   CRE += CV sin(C_th) with the mid-sample course; the position corrections C(RN), C(RE) are fed
   back after every update (closed loop: dN^, dE^ are reset to 0).
4. Updates: one scalar course update per sample, the compass course (H = [1, 1, 0, 0, 0, 0, 0])
   or, where the map-heading selector chose the street heading, the map course
   (H = [0, 1, 0, 0, 0, 0, 0], R from kf_map_sigma_deg); for the compass R = (kf_compass_sigma_deg^2 +
   kf_white_sigma_deg^2 + (kf_compass_ec_weight E_C)^2) * max(1, kf_compass_corr_m / |AD|):
   the white compass noise is counted once per kf_compass_corr_m of road, so a stationary
   vehicle gains no information from repeating the same reading, and at most once per
   compass_noise.COMPASS_CORR_S seconds (a log sampled faster than 10 Hz); position fixes (2-D,
   H = [[0, 0, 0, 1, 0, -1, 0], [0, 0, 0, 0, 1, 0, -1]], R = kf_fix_sigma_m^2 I).  Joseph form,
   then symmetrized.
   The first fix is taken without the gate (it may be far from a dead-reckoned start).

5. Re-acquisition (``_reacquire``): a course measurement that disagrees with the course by more than
   filter_reacquire_large_deg for filter_reacquire_lost_m, that is beyond the gate for filter_reacquire_m, that
   far off when the complementary filter restarts as lost, or more than CORROBORATED_DISAGREEMENT_DEG off while
   the fixes are rejected in a row, restarts dth1, dth2, eps from it; the next fix
   then repositions (``_reposition``), as does one after FIX_REACQUIRE_COUNT fixes in a row beyond the gate.

Without fixes the filter runs on the compass alone.  All noise parameters are kf_* entries of
Params; everything is jnp with masks, so it is jit/vmap/grad-safe.  Their defaults were fitted by
gradient descent on simulated drives (bench/tune_kalman.py, docs/calibration-kalman.md).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from . import fix_alignment as _align
from .angles import safe_div, wrap
from .fix_alignment import AlignmentState, init_alignment_state
from .compass_noise import samples_per_measurement
from .kalman_update import small_matmul, sparse_left_matmul, update
from .offset_filter import UNINITIALIZED_BOUND, lost, lost_distance, supported_bound
from .packed import computed_once, value_once
from .params import deg
from .rate_significance import drifting_significantly, large_drift

N_STATES = 8
MAX_DT_S = 60.0
"""Longest time step the error model propagates over (a logging gap counts as this)."""
MAX_FIX_M = _align.MAX_FIX_M
"""Fixes (and a position computer) farther than this from the origin are not plausible (m; one value with the fixes'
alignment)."""
I_GM, I_DRIFT, I_RAMP, I_N, I_E, I_FIX_N, I_FIX_E, I_RATE = range(N_STATES)
H_COMPASS = np.array([[1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
H_MAP = np.array([[0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
H_FIX = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0]])


class KalmanState(NamedTuple):
    x: jnp.ndarray        # east, m (position computer, CRE)
    y: jnp.ndarray        # north, m (position computer, CRN)
    err: jnp.ndarray      # (8,) error-state estimate [dth1, dth2, eps, dN, dE, bN, bE, beta]
    #                       (rad, rad, rad/s, m x 4, rad/m)
    cov: jnp.ndarray      # (8, 8) its covariance
    speed: jnp.ndarray    # last plausible signed speed, m/s
    active: jnp.ndarray   # 1.0 once the wheel heading has been started (filter running)
    fixes: jnp.ndarray    # number of position fixes used
    disagreement: jnp.ndarray  # running course innovation over filter_check_m (rad)
    lost_m: jnp.ndarray        # metres driven with |disagreement| beyond filter_reacquire_large_deg
    rejected_m: jnp.ndarray    # metres driven with every course measurement beyond the soft gate
    corroborated_m: jnp.ndarray  # metres driven with the fixes rejected in a row and the compass far (_reacquire)
    fix_rejected: jnp.ndarray  # fixes in a row beyond the soft gate
    reposition: jnp.ndarray    # 1.0: the next fix repositions (after a course restart or fixes rejected in a row)
    alignment: AlignmentState  # the fixes against the wheels' track before the heading is started (fix_alignment)


def initial_covariance(params):
    """P0 = diag(sigma_gm^2, sigma_heading0^2, sigma_ramp0^2, sigma_pos0^2, sigma_pos0^2, sigma_fix_gm^2,
    sigma_fix_gm^2, sigma_rate0^2)."""
    return jnp.diag(jnp.stack([
        deg(params.kf_gm_sigma_deg) ** 2,
        deg(params.kf_heading_sigma0_deg) ** 2,
        (deg(params.kf_ramp_sigma0_deg_per_min) / 60.0) ** 2,
        params.kf_pos_sigma0_m ** 2,
        params.kf_pos_sigma0_m ** 2,
        params.kf_fix_gm_sigma_m ** 2,
        params.kf_fix_gm_sigma_m ** 2,
        params.kf_rate_sigma0 ** 2,
    ]))


def init_kalman_state(params):
    z = jnp.zeros((), jnp.float64)
    return KalmanState(x=z, y=z, err=jnp.zeros((N_STATES,), jnp.float64), cov=initial_covariance(params),
                       speed=z, active=z, fixes=z, disagreement=z, lost_m=z, rejected_m=z, corroborated_m=z,
                       fix_rejected=z, reposition=z, alignment=init_alignment_state())


def transition(params, dt, s, course, alpha=0.0, turn_sigma=0.0):
    """Phi, Q of one sample: dt (s), s corrected signed distance (m), course the corrected course (rad),
    alpha the wheel course change of the sample (rad), turn_sigma (rad) the uncertainty of a turn the odometer's guard
    substituted (plausibility.py ``dD_sigma`` / track; 0 for counted turns): added to dth2's process noise."""
    # dth1 decorrelates with time and with the road driven (an anomaly is a place, not a moment).
    e1 = jnp.exp(-dt / params.kf_gm_tau_s - jnp.abs(s) / params.kf_gm_m)
    sig_gm2 = deg(params.kf_gm_sigma_deg) ** 2
    q_ramp = params.kf_ramp_psd
    q_drift = params.kf_drift_psd
    sn, cs = jnp.sin(course), jnp.cos(course)
    z = jnp.zeros_like(dt)
    one = jnp.ones_like(dt)
    ef = jnp.exp(-dt / params.kf_fix_gm_tau_s)
    phi = jnp.stack([
        jnp.stack([e1, z, z, z, z, z, z, z]),
        jnp.stack([z, one, dt, z, z, z, z, s]),
        jnp.stack([z, z, one, z, z, z, z, z]),
        jnp.stack([z, -s * sn, z, one, z, z, z, z]),
        jnp.stack([z, s * cs, z, z, one, z, z, z]),
        jnp.stack([z, z, z, z, z, ef, z, z]),
        jnp.stack([z, z, z, z, z, z, ef, z]),
        jnp.stack([z, z, z, z, z, z, z, one]),
    ])
    q11 = sig_gm2 * (1.0 - e1 * e1)
    q_rate = params.kf_rate_psd * jnp.abs(s)  # beta's random walk over the sample's metres
    q22 = (q_ramp * dt ** 3 / 3.0 + q_drift * dt + params.kf_drift_per_m * jnp.abs(s)
           + (params.kf_turn_sigma * alpha) ** 2 + turn_sigma ** 2 + q_rate * s * s / 3.0)
    q28 = q_rate * s / 2.0
    q23 = q_ramp * dt ** 2 / 2.0
    q33 = q_ramp * dt
    along = (params.kf_speed_sigma * s) ** 2          # distance-scale error, along track
    cross = (deg(params.kf_white_sigma_deg) * s) ** 2  # white course noise dth3, across track
    qp = params.kf_pos_psd * dt
    qnn = along * cs * cs + cross * sn * sn + qp
    qee = along * sn * sn + cross * cs * cs + qp
    qne = (along - cross) * sn * cs
    qf = params.kf_fix_gm_sigma_m ** 2 * (1.0 - ef * ef)
    q = jnp.stack([
        jnp.stack([q11, z, z, z, z, z, z, z]),
        jnp.stack([z, q22, q23, z, z, z, z, q28]),
        jnp.stack([z, q23, q33, z, z, z, z, z]),
        jnp.stack([z, z, z, qnn, qne, z, z, z]),
        jnp.stack([z, z, z, qne, qee, z, z, z]),
        jnp.stack([z, z, z, z, z, qf, z, z]),
        jnp.stack([z, z, z, z, z, z, qf, z]),
        jnp.stack([z, q28, z, z, z, z, z, q_rate]),
    ])
    return phi, q


PHI_PATTERN = np.array([[1, 0, 0, 0, 0, 0, 0, 0],
                        [0, 1, 1, 0, 0, 0, 0, 1],
                        [0, 0, 1, 0, 0, 0, 0, 0],
                        [0, 1, 0, 1, 0, 0, 0, 0],
                        [0, 1, 0, 0, 1, 0, 0, 0],
                        [0, 0, 0, 0, 0, 1, 0, 0],
                        [0, 0, 0, 0, 0, 0, 1, 0],
                        [0, 0, 0, 0, 0, 0, 0, 1]], dtype=bool)
"""Nonzeros of the transition matrix of ``transition`` (predict relies on it)."""


def predict(err, cov, phi, q):
    """x^- = Phi x with the position rows' course coupling removed (the corrected course already
    applies the estimated course error, so the estimated position error does not grow from it);
    P^- = Phi P Phi^T + Q, symmetrized.  Phi must have the sparsity of PHI_PATTERN."""
    x = sparse_left_matmul(PHI_PATTERN, phi, err)
    x = x.at[I_N].set(err[I_N]).at[I_E].set(err[I_E])
    # Phi (Phi P)^T = Phi P Phi^T
    p = sparse_left_matmul(PHI_PATTERN, phi, sparse_left_matmul(PHI_PATTERN, phi, cov).T) + q
    return x, 0.5 * (p + p.T)


def _samples_per_measurement(params, distance, dt, reading_dt=None):
    """How many samples make one independent course measurement: one per kf_compass_corr_m of road and at most
    one per compass_noise.COMPASS_CORR_S seconds (``dt`` the sample's time step, s; None: not counted in time), a
    reading for the samples it stands for (``reading_dt``, compass_noise.samples_per_measurement).
    10-Hz samples (0.096-0.104 s apart) are left as they were; a 50-Hz log of the same highway drive (0.6 m per
    sample against the 10-Hz log's 3 m) no longer counts 1.4 times the compass information."""
    return jnp.minimum(samples_per_measurement(params.kf_compass_corr_m, distance, dt, standing=1e9,
                                               reading_dt=reading_dt), 1e9)


def compass_noise(params, e_c, distance, dt=None, reading_dt=None):
    """Compass course variance (rad^2) for a sample covering |distance| m over ``dt`` s (see the module doc)."""
    r0 = deg(params.kf_compass_sigma_deg) ** 2 + deg(params.kf_white_sigma_deg) ** 2 + (
        params.kf_compass_ec_weight * e_c) ** 2
    return r0 * _samples_per_measurement(params, distance, dt, reading_dt)


def map_noise(params, distance, dt=None, reading_dt=None):
    """Map course variance (rad^2) for a sample covering |distance| m over ``dt`` s, counted as the compass's."""
    r0 = deg(params.kf_map_sigma_deg) ** 2 + deg(params.kf_white_sigma_deg) ** 2
    return r0 * _samples_per_measurement(params, distance, dt, reading_dt)


COURSE_STATES = (I_GM, I_DRIFT, I_RAMP)
_COURSE = np.isin(np.arange(N_STATES), COURSE_STATES)
_COURSE_BLOCK = _COURSE[:, None] | _COURSE[None, :]
"""The course states and their rows and columns of the covariance (a course restart resets them)."""


CORROBORATING_FIX_COUNT = 10
"""Fixes in a row beyond the soft gate that corroborate the compass's running disagreement (``_reacquire``)."""
CORROBORATED_DISAGREEMENT_DEG = 20.0
"""The compass's running disagreement (deg) beyond which fixes rejected in a row corroborate it (``_reacquire``)."""
CORROBORATED_M = 50.0
"""Metres driven so corroborated (counted as ``offset_filter.lost_distance``) after which the course restarts from the
compass.  Chosen on the matrix's seeds 101-109 with 1-Hz fixes (10 / 30 / 50 / 100 m: the garage starts mended at 10-50
m, two of four at 100 m, where the repositioning after FIX_REACQUIRE_COUNT fixes clears the count at parking speeds;
docs/tuning.md, stop 91)."""


def _reacquire(params, ks, err, cov, p0, nu, d2, used, valid, s, dt, course_error, lost_elsewhere):
    """Restart the course states from the course measurement when the filter has lost it (err, cov after the
    course update; nu its innovation, d2 its Mahalanobis distance squared; course_error = wrap(H_W - measured
    course)).

    The seed is silent on a filter whose course error has run away from its own covariance.  It happens: a tyre
    mismatch the parameters do not know turns the wheel course 0.2-0.6 deg per metre until the calibration
    (EP 0619873) has found it, and the soft gate then holds the compass off for the rest of the drive (matrix
    mismatch drives 70-150 deg RMSE, stop 48).  As the complementary filter's re-acquisition
    (offset_filter.update): a running disagreement beyond filter_reacquire_large_deg for filter_reacquire_lost_m,
    or every measurement beyond the gate for filter_reacquire_m, restarts dth1, dth2, eps at the measured course
    with their initial covariance (the positions keep theirs; the next fix repositions them).  So does a restart of
    the complementary filter as lost (``lost_elsewhere``: its finer judgement, a steady disagreement after
    filter_reacquire_lost_steady_m, a garage left while standing) when the measurement, valid (``valid``; ``used``
    also asks for motion), is that far from this filter's course too (parking/garage_start drives of the matrix:
    14-35 deg RMSE without it, stop 48).
    Below filter_reacquire_large_deg the compass alone is not believed (a car park turns it 30 deg for 100-500 m),
    but fixes rejected CORROBORATING_FIX_COUNT times in a row say the course is wrong too: a running disagreement
    beyond CORROBORATED_DISAGREEMENT_DEG so corroborated for CORROBORATED_M restarts the course as well.  A drive
    started in a garage whose first 30 s of fixes had pulled the course from 61 to 54 deg off was left to the
    fixes, which move a course that far off by ~0.3 deg/s (their linear error model; dth2's sigma was 0.8 deg with
    the course 50 deg off): matrix garage starts 8-16 deg RMSE with the fixes, 0.85-1.2 without (stop 91).
    Returns (err, cov, restarted, the watch fields of KalmanState).
    """
    keep = jnp.exp(-jnp.abs(s) / params.filter_check_m)
    disagreement = jnp.where(used, keep * ks.disagreement + (1.0 - keep) * nu, ks.disagreement)
    far = used & lost(params, disagreement)
    lost_m = jnp.where(far, ks.lost_m + lost_distance(jnp.abs(s), dt), jnp.where(used, 0.0, ks.lost_m))
    rejected = used & (d2 > params.kf_gate_sigma ** 2) & (params.kf_gate_sigma > 0.0)
    rejected_m = jnp.where(rejected, ks.rejected_m + jnp.abs(s), jnp.where(used, 0.0, ks.rejected_m))
    far_now = lost(params, wrap(course_error - err[I_DRIFT]))
    corroborated = used & (ks.fix_rejected >= CORROBORATING_FIX_COUNT) & (
        jnp.abs(disagreement) > deg(CORROBORATED_DISAGREEMENT_DEG))
    # Held, not cleared, while the fixes start counting again after a repositioning (FIX_REACQUIRE_COUNT): cleared
    # once the compass comes within CORROBORATED_DISAGREEMENT_DEG.
    compass_near = used & (jnp.abs(disagreement) <= deg(CORROBORATED_DISAGREEMENT_DEG))
    corroborated_m = jnp.where(corroborated, ks.corroborated_m + lost_distance(jnp.abs(s), dt),
                               jnp.where(compass_near, 0.0, ks.corroborated_m))
    # computed once: selected over err and the 8 x 8 cov, the flag's chain (through the update's d2) was otherwise
    # recomputed per element, and the Kalman step ran 2.3x slower (bench_modes; 1.3x with it).
    lost_long = (lost_m > params.filter_reacquire_lost_m) | (rejected_m > params.filter_reacquire_m)
    restart = computed_once((used & (lost_long | (corroborated_m > CORROBORATED_M)))
                           | (valid & lost_elsewhere & far_now))
    start = jnp.zeros(N_STATES).at[I_DRIFT].set(course_error)
    err = jnp.where(restart & _COURSE, start, err)
    cov = jnp.where(restart & _COURSE_BLOCK, p0, cov)
    zero = jnp.zeros_like(disagreement)
    watch = dict(disagreement=disagreement, lost_m=lost_m, rejected_m=rejected_m, corroborated_m=corroborated_m)
    return err, cov, restart, {k: jnp.where(restart, zero, v) for k, v in watch.items()}


RELEASE_DISAGREEMENT_DEG = 20.0
"""beta^ is also released (``released_rate_variance``) while the course's running disagreement with the compass
exceeds this and the rate filter's rate is significant."""
RELEASE_SHOW_RATES = 2.0
"""... and larger than this many filter_follow_show_rate (2e-4 rad/m by default), beyond the 50-110 µrad/m that slow
compass errors on hills fake (without it, matrix highway/hills/105 in the Kalman mode 4.03 -> 5.54 deg)."""


def released_rate_variance(params, rate_filter, ks):
    """The variance (rad^2/m^2) beta^, the wheel course's rate per metre, is released to this sample: the rate
    filter's beta^2 + its variance while that filter's drift is large (``rate_significance.large_drift``: a tyre
    mismatch, captured into the ratio), or while it is significant (``rate_significance.drifting_significantly``),
    larger than RELEASE_SHOW_RATES x filter_follow_show_rate, and the course has run RELEASE_DISAGREEMENT_DEG away
    from the compass (``ks.disagreement``, before this sample); else 0 (beta^ keeps its own).

    US 4,680,715 is silent on a rate it does not model.  A drift too small to be large is left to the ramp eps
    (rad/s), which the soft gate keeps from learning it once the course is far off: a hidden tyre mismatch of
    0.09 % (independent urban seed 24, the ratio missing from the parameter file) turned the course 90 deg off
    over 15 minutes while the compass, and the rate filter with it, stayed right: 58.5 deg RMSE, 8.0 with this
    (docs/tuning.md, stop 57)."""
    release = large_drift(params, rate_filter) | (
        drifting_significantly(params, rate_filter)
        & (jnp.abs(rate_filter.beta) > RELEASE_SHOW_RATES * params.filter_follow_show_rate)
        & (jnp.abs(ks.disagreement) > deg(RELEASE_DISAGREEMENT_DEG)))
    return jnp.where(release, rate_filter.beta ** 2 + rate_filter.p11, 0.0)


FIX_REACQUIRE_COUNT = 30
"""Fixes in a row beyond the soft gate after which the next one repositions (30 s of 1-Hz fixes)."""
REPOSITION_SIGMA_M = 1.0e5
"""Position sigma (m) that a repositioning fix starts from: the fix, not the dead-reckoned position, decides."""


def _reposition(cov, repositions):
    """The covariance a repositioning fix is taken with: the position errors dN, dE uncorrelated with the rest,
    of sigma REPOSITION_SIGMA_M, so that the fix moves the position and nothing else.

    After a course restart the position computer has dead-reckoned with the wrong course (a drive started in a
    garage: 1.5 km at 139 deg off), and the gated fixes pulled the restarted course 57 deg away again to explain
    that position error (stop 48, highway/garage_start/101 with fixes); fixes rejected FIX_REACQUIRE_COUNT times
    in a row say the same of the position."""
    pos = np.zeros(N_STATES, dtype=bool)
    pos[[I_N, I_E]] = True
    cross = pos[:, None] | pos[None, :]
    fresh = jnp.where(np.diag(pos), REPOSITION_SIGMA_M ** 2, 0.0)
    return jnp.where(repositions & cross, fresh, cov)


def bound(params, ks, initialized):
    """Heading bound (rad) of the Kalman mode's course C_th = H_W - dth2^: the sigma of dth2, at least the running
    disagreement with the compass while it is beyond filter_reacquire_large_deg (as offset_filter.bound);
    offset_filter.UNINITIALIZED_BOUND before the start and while the course is re-aligned to the fixes."""
    supported = supported_bound(params, ks.cov[I_DRIFT, I_DRIFT], ks.disagreement, initialized)
    return jnp.where(ks.alignment.realigning > 0.5, UNINITIALIZED_BOUND, supported)


def align_before(params, ks, *, dt, distance, alpha, wheel_heading, fix_east, fix_north, fix_valid, uninitialized,
                 compass_ok=False):
    """The fixes' alignment (jaxmodel/fix_alignment.py) before the sample's Kalman step.

    Until the heading is started (``uninitialized``: no compass has) the wheels' track runs in the unstarted wheel
    heading's frame (``wheel_heading``: H_W before the sample, alpha its change); while re-aligning, on the Kalman
    course C_th = H_W - dth2^ (with beta^'s part of the sample).  Returns (AlignmentState, started: the heading is
    started at H_W + theta, realigned: C_th turns by theta, theta (rad), its sigma (rad)).  A valid compass sample
    (``compass_ok``) ends the fixes' hold on the course: no re-alignment from then on (the compass re-acquires)."""
    al = _align.done(ks.alignment, compass_ok, by_fixes=0.0)
    realigning = al.realigning > 0.5
    frozen_course = wheel_heading + 0.5 * alpha - al.frozen_drift - 0.5 * al.frozen_rate * distance
    course = wrap(jnp.where(realigning, frozen_course, wheel_heading + 0.5 * alpha))
    al, aligned, theta, sigma = _align.update(params, al, dt=dt, distance=distance, course=course, fix_east=fix_east,
                                              fix_north=fix_north, fix_valid=fix_valid,
                                              waiting=uninitialized | realigning)
    return _align.run_frozen(al, distance), aligned & ~realigning, aligned & realigning, theta, sigma


REALIGN_FIX_COUNT = 10
"""Fixes in a row beyond the soft gate after which a heading the fixes started is re-aligned (``align_after``).
Chosen on the matrix's mismatch drives of seeds 101 and 104 with their compass removed (12 drives, RMSE after the
first minute summed: 160 deg at FIX_REACQUIRE_COUNT's 30, 60 at 5, 53 at 10, 51 at 10 with the count cleared by a
re-alignment, as kept; the no-compass drives without a mismatch never re-align at any of them); judged on
independent drives (seeds 17-18, tyre mismatch hidden, compass removed, 1-Hz fixes of 4 m): 4.0-23.7 deg at 30,
1.0-10.5 at 10 (with the compass: 0.6-1.5)."""


def align_after(params, ks, heading, started, realigned, theta, sigma, fix_east, fix_north, track):
    """The Kalman state after a sample whose fix started (``started``) or re-aligned (``realigned``) the course
    by theta of sigma (rad): the position at that fix and dth2's variance at least sigma^2.

    A heading the fixes started (no compass) is re-aligned once the filter has rejected REALIGN_FIX_COUNT fixes in a
    row: the course is lost, and only the fixes can find it.  The sums run again on the
    course as it was (its dth2^ run on by its beta^, frozen: the filter's own runs off meanwhile), and the re-aligned
    course restarts as by ``_reacquire``, with beta^ the frozen one released to a variance of
    (cal_max_correction / track)^2: a tyre mismatch nobody measured is what the fixes alone must find (matrix drives
    with the compass removed and 1.5-2.5 % hidden: 100 deg RMSE without, stop 49).  The first start keeps beta
    known: released there, it took the fixes' coloured errors for drift (no-compass drives 0.39 -> 0.51 deg urban,
    1.3 -> 3.9 deg parking).  Returns (state, heading, east, north)."""
    hit = computed_once(started | realigned)
    realigned = computed_once(realigned)
    cov = jnp.where(realigned & _COURSE_BLOCK, initial_covariance(params), ks.cov)
    # The frozen course turned by theta: dth2^ = frozen dth2 - theta, beta^ the frozen one (the filter's own ran off).
    frozen = ks.alignment.fields()
    err = ks.err.at[I_DRIFT].set(jnp.where(realigned, frozen.frozen_drift - theta, ks.err[I_DRIFT]))
    err = err.at[I_RATE].set(jnp.where(realigned, frozen.frozen_rate, err[I_RATE]))
    rate_sigma = params.cal_max_correction / track
    cov = cov.at[I_DRIFT, I_DRIFT].set(jnp.where(hit, jnp.maximum(cov[I_DRIFT, I_DRIFT], sigma ** 2),
                                                 cov[I_DRIFT, I_DRIFT]))
    cov = cov.at[I_RATE, I_RATE].set(jnp.where(realigned, jnp.maximum(cov[I_RATE, I_RATE], rate_sigma ** 2),
                                               cov[I_RATE, I_RATE]))
    east = jnp.where(hit, fix_east, ks.x)
    north = jnp.where(hit, fix_north, ks.y)
    al = _align.done(ks.alignment, hit)
    lost_fixes = computed_once((al.by_fixes > 0.5) & (al.realigning < 0.5) & (ks.fix_rejected >= REALIGN_FIX_COUNT)
                               & ~hit)
    al = AlignmentState(jnp.where(lost_fixes, _align.again(al, ks.err[I_DRIFT], ks.err[I_RATE]).vector, al.vector))
    heading = jnp.where(realigned, wrap(heading + ks.err[I_DRIFT] - err[I_DRIFT]), heading)
    rejected = jnp.where(hit, 0.0, ks.fix_rejected)
    return ks._replace(x=east, y=north, err=err, cov=cov, alignment=al, fix_rejected=rejected), heading, east, north


def kalman_step(params, ks, *, dt, distance, alpha, wheel_heading, compass_heading, compass_ok, e_c,
                fix_east, fix_north, fix_valid, odometer_ok, initialized, map_heading=0.0, map_used=False,
                enabled=True, dt_counts=None, held=False, rate_change=0.0, rate_variance=0.0, lost_elsewhere=False,
                reading_dt=None, turn_sigma=0.0):
    """One sample (US 4,680,715 claim 1).  Returns (new KalmanState, corrected course C_th [rad], east [m], north [m]).

    dt: sample interval (0 when unusable); distance: signed AD (m) with the calibrated dpp; dt_counts: the time
    it covers (since the counts last changed; dt if None); held: the counts repeat the last ones (no news of speed);
    alpha: wheel heading change of the sample (rad); wheel_heading: H_W after it;
    compass_heading: H_C (valid where compass_ok); e_c: compass error bound (rad);
    map_heading, map_used: the street heading chosen by the map-heading selector (FIG. 8F) and
    whether it replaced the compass on this sample;
    odometer_ok: the odometer's own plausibility of the counts; initialized: H_W has been
    started (1.0); rate_change: the change of the wheel course's rate per metre by a new left/right calibration
    this sample (rad/m, drift_capture.calibrate), which beta^ follows; rate_variance: the variance beta^ is released to
    (rad^2/m^2); lost_elsewhere: the complementary filter restarted as lost on this sample (see _reacquire);
    reading_dt: the seconds since the previous compass reading (compass.reading_interval; dt if None);
    turn_sigma: the uncertainty (rad) of a turn the odometer's guard substituted for a wheel that stopped counting
    (0 for counted turns), dth2's process noise as in F-DELTA (offset_filter.predict).
    ``enabled`` is static: False (other modes) passes the state through.
    """
    if not enabled:
        return ks, wheel_heading, ks.x, ks.y
    active = computed_once(ks.active > 0.5)
    p0 = initial_covariance(params)
    dt, speed, dist_used, course_ok = _plausible_motion(params, ks, dt, distance, alpha, odometer_ok, dt_counts, held)
    # 2. DF(V).
    s = params.kf_speed_factor * dist_used
    err_p, cov_p = _predicted(params, ks, active, p0, dt, s, alpha, wheel_heading, course_ok, rate_change,
                              rate_variance, turn_sigma)
    # 3. Position computer with the corrected course.
    course_mid = wrap(wheel_heading - 0.5 * alpha - err_p[I_DRIFT])
    north = ks.y + s * jnp.cos(course_mid)
    east = ks.x + s * jnp.sin(course_mid)
    err_u, cov_u, restarted, watch = _course_update(
        params, ks, err_p, cov_p, p0, active, s, dt, wheel_heading, compass_heading, compass_ok, e_c, map_heading,
        map_used, lost_elsewhere, reading_dt)
    err_u, cov_u, fix_ok, fix_rejected, reposition = _fix_update(params, ks, err_u, cov_u, active, north, east,
                                                                 fix_east, fix_north, fix_valid, restarted)
    # Feed the position corrections C(RN), C(RE) back and reset their error states.
    north = north - err_u[I_N]
    east = east - err_u[I_E]
    err_u = err_u.at[I_N].set(0.0).at[I_E].set(0.0)
    heading = jnp.where(active, wrap(wheel_heading - err_u[I_DRIFT]), wheel_heading)
    new = KalmanState(
        x=east, y=north,
        err=jnp.where(active, err_u, jnp.zeros_like(err_u)),
        cov=jnp.where(active, cov_u, p0),
        speed=speed,
        active=jnp.where(initialized > 0.5, 1.0, 0.0),
        fixes=ks.fixes + jnp.where(fix_ok, 1.0, 0.0),
        **{k: jnp.where(active, v, 0.0) for k, v in watch.items()},
        fix_rejected=jnp.where(active, fix_rejected, 0.0), reposition=jnp.where(active & reposition, 1.0, 0.0),
        alignment=ks.alignment,
    )
    return new, heading, east, north


def _plausible_motion(params, ks, dt, distance, alpha, odometer_ok, dt_counts, held):
    """Step 1 of claim 1, the plausibility of speed and course.  Returns (dt clipped to MAX_DT_S, the speed, the
    distance used (m; slewed at kf_max_accel where implausible), whether the course change is plausible)."""
    dpp = jnp.maximum(params.dpp_left, params.dpp_right)
    track = jnp.minimum(params.T_F, params.T_R)
    # A gap longer than MAX_DT_S propagates as MAX_DT_S
    # (the noise models are for normal sampling; an absurd time step must not overflow Q).
    dt = jnp.clip(dt, 0.0, MAX_DT_S)
    time_ok = dt > 0.0
    dt_counts = dt if dt_counts is None else jnp.clip(dt_counts, 0.0, MAX_DT_S)
    v_meas = safe_div(distance, dt_counts)
    dv_max = params.kf_max_accel * dt_counts + safe_div(2.0 * dpp, dt_counts)
    speed_ok = odometer_ok & (jnp.abs(v_meas - ks.speed) <= dv_max)
    dv_slew = params.kf_max_accel * dt_counts
    v_slew = ks.speed + jnp.clip(v_meas - ks.speed, -dv_slew, dv_slew)
    speed = jnp.where(time_ok & ~held, jnp.where(speed_ok, v_meas, v_slew), ks.speed)
    dist_used = jnp.where(time_ok & ~speed_ok & ~held, v_slew * dt_counts, distance)
    course_limit = deg(params.kf_max_yaw_rate_deg_s) * dt_counts + 4.0 * dpp / track
    return dt, speed, dist_used, jnp.abs(alpha) <= course_limit


def _predicted(params, ks, active, p0, dt, s, alpha, wheel_heading, course_ok, rate_change, rate_variance,
               turn_sigma=0.0):
    """The error state and covariance predicted over the sample (the filter runs only once H_W has been started;
    before, P0): an implausible course change goes into dth2, a new calibration's rate change into beta."""
    err = jnp.where(active, ks.err, 0.0)
    cov = jnp.where(active, ks.cov, p0)
    err = err.at[I_DRIFT].add(jnp.where(active & ~course_ok, alpha, 0.0))
    err = err.at[I_RATE].add(jnp.where(active, rate_change, 0.0))
    cov = cov.at[I_RATE, I_RATE].max(jnp.where(active, rate_variance, 0.0))
    course_est = err[I_DRIFT]
    course_mid = wrap(wheel_heading - 0.5 * alpha - course_est)
    phi, q = transition(params, dt, s, course_mid, jnp.where(course_ok, alpha, 0.0), turn_sigma)
    err_p, cov_p = predict(err, cov, phi, q)
    return jnp.where(active, err_p, err), jnp.where(active, cov_p, cov)


def _course_update(params, ks, err_p, cov_p, p0, active, s, dt, wheel_heading, compass_heading, compass_ok, e_c,
                   map_heading, map_used, lost_elsewhere, reading_dt=None):
    """Step 4a, the course update, and the re-acquisition after it (``_reacquire``).  Returns (err, cov,
    restarted, the watch fields of KalmanState).  ``reading_dt`` (s): the compass reading's interval (None: ``dt``)."""
    # The compass course (H_COMPASS) or, where the map-heading selector of
    # US 4,734,863 FIG. 8F chose the street heading (course support data of the seed's input
    # means), the map course (H_MAP: the compass's colored error dth1 is not in it).
    # One scalar update serves both (they never happen on the same sample): H_MAP is H_COMPASS
    # with the dth1 entry zeroed, so the static pattern is H_COMPASS's and the entry is traced.
    h_course = jnp.where(map_used, jnp.asarray(H_MAP), jnp.asarray(H_COMPASS))
    course_meas = jnp.where(map_used, map_heading, compass_heading)
    nu_c = wrap(wrap(wheel_heading - course_meas) - small_matmul(h_course[0], err_p))
    r_c = jnp.where(map_used, map_noise(params, s, dt, reading_dt), compass_noise(params, e_c, s, dt, reading_dt))
    valid_c = active & (compass_ok | map_used)
    use_c = valid_c & (jnp.abs(s) > 0.0)
    err_u, cov_u, d2_c = update(err_p, cov_p, nu_c[None], h_course, r_c[None, None], use_c, params.kf_gate_sigma,
                                pattern=H_COMPASS != 0.0)
    return _reacquire(params, ks, err_u, cov_u, p0, nu_c, d2_c, use_c, valid_c, s, dt,
                      wrap(wheel_heading - course_meas), lost_elsewhere)


def _fix_update(params, ks, err, cov, active, north, east, fix_east, fix_north, fix_valid, restarted):
    """Step 4b, the position fix update (the first fix without the gate; see _reposition).  Returns (err, cov,
    fix_ok, fix_rejected, reposition: the next fix repositions)."""
    fix_ok = computed_once(active & (fix_valid > 0.5) & (jnp.abs(fix_east) < MAX_FIX_M)
                           & (jnp.abs(fix_north) < MAX_FIX_M) & (jnp.abs(ks.x) < MAX_FIX_M)
                           & (jnp.abs(ks.y) < MAX_FIX_M))  # also false for NaN/inf
    fe = jnp.where(fix_ok, fix_east, 0.0)
    fn = jnp.where(fix_ok, fix_north, 0.0)
    nu_f = jnp.stack([north - fn - (err[I_N] - err[I_FIX_N]), east - fe - (err[I_E] - err[I_FIX_E])])
    r_f = params.kf_fix_sigma_m ** 2 * jnp.eye(2)
    repositions = computed_once(fix_ok & (ks.reposition > 0.5))
    cov = _reposition(cov, repositions)
    gate_f = jnp.where((ks.fixes > 0.5) & ~repositions, params.kf_gate_sigma, 0.0)
    err, cov, d2_f = update(err, cov, nu_f, H_FIX, r_f, fix_ok, gate_f)
    far = fix_ok & ~repositions & (d2_f > params.kf_gate_sigma ** 2) & (params.kf_gate_sigma > 0.0)
    fix_rejected = value_once(jnp.where(fix_ok, jnp.where(far, ks.fix_rejected + 1.0, 0.0), ks.fix_rejected))
    reposition = restarted | (fix_rejected >= FIX_REACQUIRE_COUNT) | ((ks.reposition > 0.5) & ~repositions)
    fix_rejected = jnp.where(fix_rejected >= FIX_REACQUIRE_COUNT, 0.0, fix_rejected)
    return err, cov, fix_ok, fix_rejected, reposition
