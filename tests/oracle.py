"""A slow, literal transcription of the seeds, used only as a test oracle and as the
reference loop of bench/bench_run.py.  Plain Python floats, one sample at a time.

Covers the complementary mode with refinement of a and calibration off:
US 4,788,645 eq. (8), (14); US 4,734,863 FIG. 8A-8H (with the choices documented in jaxmodel:
eq. (14) evaluated per interval of curvature_window_m travelled metres, start-up floor of the filter
gain, |E_h| in FIG. 8E block 5).
"""

import math


def wrap(a):
    a = math.fmod(a + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


def effective_track(c, P, B, T_F, clip=0.98):
    k = (2 * B / T_F) ** 2
    c = min(abs(c), clip / math.sqrt(k + 0.25))
    q = c * c / (1 - 0.25 * c * c) * k
    return T_F * (P + (1 - P) * math.sqrt(0.5 + 0.5 * math.sqrt(max(1 - q, 0.0))))


def run_reference(p, t, left, right, cx, cy):
    """p: dict of parameter values (JSON keys); sequences of samples. Returns list of EH (rad)."""
    rad = math.pi / 180
    mod = p["counter_modulus"]
    out = []
    last_t, last_l, last_r = t[0], left[0], right[0]
    speed = 0.0
    i_num = i_dD = i_AD = i_turn = 0.0  # the curvature interval: sums of dD / (1 + a V^2), signed dD, |AD|
    H_W = F_DELTA = E_W = SDD = 0.0
    F = 1.0
    hist = [0.0, 0.0, 0.0]
    dist_F = dist_filt = 0.0
    field_sum = field_n = 0.0
    init = False
    e_c = 0.0
    for i in range(len(t)):
        # FIG. 8B block 1: wheel distances from wrapping counters
        if i == 0:
            nl = nr = 0.0
            dt = 0.0
        else:
            dt = t[i] - last_t
            nl = left[i] - last_l
            nl -= mod * round(nl / mod)
            nr = right[i] - last_r
            nr -= mod * round(nr / mod)
        last_t, last_l, last_r = t[i], left[i], right[i]
        dl, dr = nl * p["dpp_left"], nr * p["dpp_right"]
        dD, AD = dl - dr, 0.5 * (dl + dr)
        d_t = abs(AD)
        if dt > 0:
            speed = d_t / dt
        # US 4,788,645 eq. (8) and (14) over the interval so far (its dD/AD), re-evaluated every sample
        i_num += dD / (1 + p["a"] * speed**2)
        i_dD += dD if AD >= 0 else -dD
        i_AD += d_t
        c = i_dD / i_AD if i_AD > 1e-9 else 0.0
        T = effective_track(c, p["P"], p["B"], p["T_F"], p["curvature_clip"]) if p["sensor_axle"] == "front" else p["T_R"]
        alpha = i_num / T - i_turn
        i_turn = i_num / T
        if i_AD >= p["curvature_window_m"]:
            i_num = i_dD = i_AD = i_turn = 0.0
        # FIG. 8A
        x, y = cx[i] - p["X0"], cy[i] - p["Y0"]
        H_C = wrap(math.atan2(y, x) - p["rotation_deg"] * rad + p["variation_deg"] * rad)
        B_M = math.hypot(x, y)
        field_sum += B_M
        field_n += 1
        B_E = p["field_magnitude"] if p["field_magnitude"] > 0 else field_sum / field_n
        # FIG. 8C
        e_c = max(abs(B_M - B_E) / B_E * p["compass_error_scale_deg"] * rad, p["compass_error_floor_deg"] * rad)
        if not init:
            H_W, init, first = H_C, True, True
        else:
            H_W, first = wrap(H_W + alpha), False
        # FIG. 8D
        E_W = (E_W + abs(alpha * p["wheel_error_K"])) * min(max(1 - d_t / p["D_N"], 0.0), 1.0)
        DELTA = wrap(H_C - H_W)
        # FIG. 8 block 6, 8E/A, 8E
        dist_F += d_t
        if dist_F >= p["F_update_distance_m"]:
            hist = [DELTA] + hist[:2]
            rel = [wrap(h - hist[0]) for h in hist]
            m = sum(rel) / 3
            SD_N = math.sqrt(sum((r - m) ** 2 for r in rel) / 3)
            T6 = p["sdd_T"]
            SDD = max(SD_N, SD_N / T6 + (T6 - 1) / T6 * SDD)
            E_h = SDD * p["heading_error_K"] * (E_W - e_c)
            F = (E_h + p["K1"]) / p["K1"] if E_h > 0 else p["K2"] / (abs(E_h) + p["K2"])
            dist_F = 0.0
        # FIG. 8G
        dist_filt += d_t
        gain = d_t * F / p["D_N"]
        if dist_filt > 1e-9:
            gain = max(gain, d_t / dist_filt)
        gain = min(max(gain, 0.0), 1.0)
        F_DELTA = 0.0 if first else wrap(F_DELTA + gain * wrap(DELTA - F_DELTA))
        # FIG. 8H
        out.append(wrap(H_W + F_DELTA))
    return out
