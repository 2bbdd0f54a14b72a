"""Kalman-filter mode, US 4,680,715 (jaxmodel/kalman.py)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmodel as jm
from jaxmodel import kalman as K


def _np_matrices(p, dt, s, course):
    """Phi, Q written again in NumPy from the formulas of jaxmodel/kalman.py's docstring."""
    d = math.radians
    e1 = math.exp(-dt / p["kf_gm_tau_s"])
    sn, cs = math.sin(course), math.cos(course)
    phi = np.eye(5)
    phi[0, 0] = e1
    phi[1, 2] = dt
    phi[3, 0] = phi[3, 1] = -s * sn
    phi[4, 0] = phi[4, 1] = s * cs
    q = np.zeros((5, 5))
    q[0, 0] = d(p["kf_gm_sigma_deg"]) ** 2 * (1 - e1 ** 2)
    qr, qd = p["kf_ramp_psd"], p["kf_drift_psd"]
    q[1, 1] = qr * dt ** 3 / 3 + qd * dt
    q[1, 2] = q[2, 1] = qr * dt ** 2 / 2
    q[2, 2] = qr * dt
    along = (p["kf_speed_sigma"] * s) ** 2
    cross = (d(p["kf_white_sigma_deg"]) * s) ** 2
    u = np.array([cs, sn])
    v = np.array([-sn, cs])
    q[3:, 3:] = along * np.outer(u, u) + cross * np.outer(v, v) + p["kf_pos_psd"] * dt * np.eye(2)
    return phi, q


def _np_kf(p, samples, p0):
    """A plain textbook Kalman filter (standard-form covariance update, np.linalg.inv)."""
    d = math.radians
    x = np.zeros(5)
    P = p0.copy()
    north = east = 0.0
    out = []
    for smp in samples:
        dt, s, h_w, h_c, e_c, fix = smp["dt"], smp["s"], smp["h_w"], smp["h_c"], smp["e_c"], smp["fix"]
        course = h_w - (x[0] + x[1])  # alpha = 0: mid-sample course = course after the sample
        phi, q = _np_matrices(p, dt, s, course)
        x_pos = x[3:].copy()
        x = phi @ x
        x[3:] = x_pos  # the corrected course already applies the estimated course error
        P = phi @ P @ phi.T + q
        course = h_w - (x[0] + x[1])
        north += s * math.cos(course)
        east += s * math.sin(course)
        # compass course
        H = np.array([[1.0, 1.0, 0, 0, 0]])
        R = (d(p["kf_compass_sigma_deg"]) ** 2 + d(p["kf_white_sigma_deg"]) ** 2
             + (p["kf_compass_ec_weight"] * e_c) ** 2) * max(1.0, p["kf_compass_corr_m"] / abs(s))
        z = np.array([h_w - h_c])
        Kg = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        x = x + Kg @ (z - H @ x)
        P = (np.eye(5) - Kg @ H) @ P
        if fix is not None:
            H = np.zeros((2, 5))
            H[0, 3] = H[1, 4] = 1.0
            R = p["kf_fix_sigma_m"] ** 2 * np.eye(2)
            z = np.array([north - fix[1], east - fix[0]])
            Kg = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
            x = x + Kg @ (z - H @ x)
            P = (np.eye(5) - Kg @ H) @ P
        north -= x[3]
        east -= x[4]
        x[3:] = 0.0
        out.append((h_w - (x[0] + x[1]), east, north, x.copy(), P.copy()))
    return out


def test_equals_numpy_kalman_on_linear_case():
    """Straight drive at constant course: the error-state model is linear; JAX == NumPy."""
    p = jm.make_params(kf_gate_sigma=0.0, kf_ramp_psd=1e-9, kf_drift_psd=1e-5)
    pd = jm.params_to_dict(p)
    rng = np.random.default_rng(3)
    n, dt, v = 600, 0.1, 12.0
    h_w = 0.4
    true_course = h_w - math.radians(2.0) - 1e-4 * np.arange(n) * dt  # wheel course error: offset + ramp
    samples = []
    tn = te = 0.0
    for k in range(n):
        s = v * dt
        tn += s * math.cos(true_course[k])
        te += s * math.sin(true_course[k])
        fix = None
        if k % 10 == 9:
            fix = (te + 4.0 * rng.standard_normal(), tn + 4.0 * rng.standard_normal())
        samples.append(dict(dt=dt, s=s, h_w=h_w, h_c=true_course[k] + math.radians(1.5) * rng.standard_normal(),
                            e_c=math.radians(1.0 + 0.5 * (k % 7)), fix=fix))

    ks = K.init_kalman_state(p)._replace(active=jnp.ones(()), speed=jnp.asarray(v))  # plausible from the start
    p0 = np.asarray(K.initial_covariance(p))

    def body(ks, smp):
        ks, heading, east, north = K.kalman_step(
            p, ks, dt=smp["dt"], distance=smp["s"], alpha=0.0, wheel_heading=smp["h_w"], compass_heading=smp["h_c"],
            compass_ok=True, e_c=smp["e_c"], fix_east=smp["fe"], fix_north=smp["fn"], fix_valid=smp["fv"],
            odometer_ok=True, initialized=1.0)
        return ks, (heading, east, north, ks.err, ks.cov)

    xs = {k: jnp.asarray([s[k] for s in samples]) for k in ("dt", "s", "h_w", "h_c", "e_c")}
    xs["fe"] = jnp.asarray([s["fix"][0] if s["fix"] else 0.0 for s in samples])
    xs["fn"] = jnp.asarray([s["fix"][1] if s["fix"] else 0.0 for s in samples])
    xs["fv"] = jnp.asarray([1.0 if s["fix"] else 0.0 for s in samples])
    _, (heading, east, north, err, cov) = jax.jit(lambda ks, xs: jax.lax.scan(body, ks, xs))(ks, xs)

    ref = _np_kf(pd, samples, p0)
    np.testing.assert_allclose(np.asarray(heading), [r[0] for r in ref], rtol=0, atol=1e-10)
    np.testing.assert_allclose(np.asarray(east), [r[1] for r in ref], rtol=0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(north), [r[2] for r in ref], rtol=0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(err), np.array([r[3] for r in ref]), rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(np.asarray(cov), np.array([r[4] for r in ref]), rtol=1e-6, atol=1e-12)
    # and the filter did its job: the 2 deg course error is found
    assert abs(float(heading[-1]) - true_course[-1]) < math.radians(0.5)


def test_update_matches_textbook_on_random_system():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 5))
    P = A @ A.T + np.eye(5)
    x = rng.standard_normal(5)
    for m in (1, 2):
        H = rng.standard_normal((m, 5))
        R = np.eye(m) * 0.7
        nu = rng.standard_normal(m)
        xj, Pj, _ = K.update(jnp.asarray(x), jnp.asarray(P), jnp.asarray(nu), jnp.asarray(H), jnp.asarray(R), True, 0.0)
        Kg = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        np.testing.assert_allclose(np.asarray(xj), x + Kg @ nu, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(Pj), (np.eye(5) - Kg @ H) @ P, rtol=1e-10, atol=1e-12)
        xj, Pj, _ = K.update(jnp.asarray(x), jnp.asarray(P), jnp.asarray(nu), jnp.asarray(H), jnp.asarray(R), False, 0.0)
        np.testing.assert_array_equal(np.asarray(xj), x)
        np.testing.assert_allclose(np.asarray(Pj), P, rtol=1e-15)
