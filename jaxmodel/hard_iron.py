"""Online hard-iron estimate: the compass offsets X0, Y0 learned from the field seen while turning.

US 4,734,863 FIG. 8A block 2 subtracts fixed offsets, "X2 equal to X1 - X0 and Y2 equal to
Y1 - Y0; where X0 and Y0 are the compass offsets"; its deviation table and rotation R are
"calculated during calibration", and its expected field B_E is measured "by orienting the
compass means 23 in a number of known headings" (description of means 32, FIG. 8C).  The seed
does not say how X0/Y0 are found, and nothing in it updates them while driving (issue 14 says
it does; the text we have does not): the online estimate here is our extension, for a compass
that was never calibrated or whose vehicle's magnetisation changed.  It uses what the seed's calibration uses,
the horizontal field seen at several headings, and takes the headings from the drive's own turns.

Model.  Without offsets the horizontal field (x, y) lies on a circle of radius r (the earth's
horizontal field) around (X0, Y0) at every heading:

    (x - X0)^2 + (y - Y0)^2 = r^2   <=>   x^2 + y^2 = 2 X0 x + 2 Y0 y + (r^2 - X0^2 - Y0^2),

linear in (X0, Y0, c = r^2 - X0^2 - Y0^2): an algebraic (Kasa) least-squares circle fit.  With
z = x^2 + y^2 and the weighted means over the samples its solution is

    C (X0, Y0)^T = 1/2 cov(p, z),   C = cov(p) (2 x 2),   r^2 = E|p - (X0, Y0)|^2,

so the state is nine forgetful weighted sums (weight, x, y, xx, xy, yy, z, xz, yz), updated
recursively (recursive least squares in information form):

    S <- exp(-d / hard_iron_memory_m) S + w s(x, y),   w = d / (1 + (e / (hard_iron_gate x r))^2)

per sample: d the distance driven in the sample (no learning while standing still), e the
distance of the sample from the current circle (|p - O| - r; a Cauchy weight that keeps
anomalies and a parked truck from pulling the fit, and still lets a changed offset in), the
compass valid and not in a map-flagged unreliable area.

Acceptance: the fit is ill-conditioned until the samples span enough heading (a straight
drive sees one point of the circle).  The spread is measured by the wheels, not by the fit
(an arc of noisy samples also fits a small circle well): psi, the sum of the wheel turns alpha,
and the same forgetful weighted sums of cos psi and sin psi give the mean resultant length
R = |E[exp(i psi)]|, which is sin(A/2) / (A/2) for headings covering an arc of width A
uniformly.  The fit is accepted when R is below that value for A = ``hard_iron_min_turn_deg``,
the sums hold more than ``hard_iron_min_distance_m`` metres and r^2 > 0; otherwise the last
accepted offsets stay (at the start: the parameters' X0, Y0).  ``restart`` is true at the first accepted fit that
moves the offsets by more than ``hard_iron_restart_fraction`` of r: the estimator then starts its heading
again from the corrected compass (jaxmodel/model.py).

All sums are taken relative to the parameters' X0, Y0 (less cancellation).  Everything is
elementwise and float64 (a 2 x 2 solve written out), differentiable with finite gradients.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .angles import safe_div, safe_sqrt
from .packed import packed_state
from .params import deg


class HardIronFields(NamedTuple):
    """Forgetful weighted sums (weight in m; coordinates relative to the parameters' X0, Y0),
    the accepted offsets X0, Y0 (compass units, absolute), the accepted radius r and whether a
    fit was ever accepted (0/1)."""

    w: jnp.ndarray
    sx: jnp.ndarray
    sy: jnp.ndarray
    sxx: jnp.ndarray
    sxy: jnp.ndarray
    syy: jnp.ndarray
    sz: jnp.ndarray
    sxz: jnp.ndarray
    syz: jnp.ndarray
    psi: jnp.ndarray
    sc: jnp.ndarray
    ss: jnp.ndarray
    X0: jnp.ndarray
    Y0: jnp.ndarray
    radius: jnp.ndarray
    accepted: jnp.ndarray


HardIronState = packed_state(HardIronFields, "HardIronState",
                             "State of the online hard-iron estimate (one float64 vector).")


def init_hard_iron_state(params):
    """No samples; the offsets are the parameters' X0, Y0."""
    z = jnp.zeros((), jnp.float64)
    return HardIronState.pack(HardIronFields(
        w=z, sx=z, sy=z, sxx=z, sxy=z, syy=z, sz=z, sxz=z, syz=z, psi=z, sc=z, ss=z,
        X0=jnp.asarray(params.X0, jnp.float64), Y0=jnp.asarray(params.Y0, jnp.float64), radius=z, accepted=z))


def resultant_of_arc(turn):
    """Mean resultant length |E[exp(i psi)]| of headings uniform over an arc of ``turn`` rad (<= 2 pi)."""
    half = 0.5 * jnp.clip(turn, 1e-3, 2.0 * jnp.pi)
    return jnp.sin(half) / half


def offsets(hs):
    """(X0, Y0) to subtract from this sample's compass components."""
    return hs.X0, hs.Y0


def solve(f):
    """(X0, Y0 relative to the parameters', r^2, smallest eigenvalue of C) of the sums ``f``."""
    w = jnp.maximum(f.w, 1e-12)
    mx, my, mz = f.sx / w, f.sy / w, f.sz / w
    cxx = f.sxx / w - mx * mx
    cxy = f.sxy / w - mx * my
    cyy = f.syy / w - my * my
    cxz = f.sxz / w - mx * mz
    cyz = f.syz / w - my * mz
    det = cxx * cyy - cxy * cxy
    ox = 0.5 * safe_div(cyy * cxz - cxy * cyz, det, eps=1e-30)
    oy = 0.5 * safe_div(cxx * cyz - cxy * cxz, det, eps=1e-30)
    r2 = mz - 2.0 * (ox * mx + oy * my) + ox * ox + oy * oy
    half_trace = 0.5 * (cxx + cyy)
    lam_min = half_trace - safe_sqrt(jnp.maximum(half_trace * half_trace - det, 0.0))
    return ox, oy, r2, lam_min


def update(params, hs, compass_x, compass_y, d_t, alpha, use):
    """Learn from one sample (compass components, distance d_t in m, wheel turn alpha in rad, ``use`` a bool mask).

    Returns (new state, restart): restart is true when this sample's accepted fit is the first
    and moved the offsets by more than hard_iron_restart_fraction of the field radius.
    """
    f = hs.fields()
    finite = jnp.isfinite(compass_x) & jnp.isfinite(compass_y)
    px = jnp.where(finite, compass_x - params.X0, 0.0)
    py = jnp.where(finite, compass_y - params.Y0, 0.0)
    ok = use & finite & (d_t > 0.0) & (jnp.abs(px) < 1e100) & (jnp.abs(py) < 1e100)
    px = jnp.where(ok, px, 0.0)
    py = jnp.where(ok, py, 0.0)

    # Cauchy weight by the distance from the accepted circle (all samples count before a fit is accepted).
    ex, ey = px - (f.X0 - params.X0), py - (f.Y0 - params.Y0)
    e = safe_sqrt(ex * ex + ey * ey) - f.radius
    scale = params.hard_iron_gate * f.radius
    robust = 1.0 / (1.0 + safe_div(e, scale, eps=1e-12, fallback=0.0) ** 2)
    weight = jnp.where(ok, d_t * jnp.where(f.accepted > 0.5, robust, 1.0), 0.0)
    forget = jnp.exp(-jnp.where(ok, d_t, 0.0) / params.hard_iron_memory_m)
    z = px * px + py * py
    psi = f.psi + jnp.where(jnp.isfinite(alpha), alpha, 0.0)
    psi = psi - 2.0 * jnp.pi * jnp.round(psi / (2.0 * jnp.pi))
    sums = [forget * s + weight * v for s, v in zip(
        (f.w, f.sx, f.sy, f.sxx, f.sxy, f.syy, f.sz, f.sxz, f.syz, f.sc, f.ss),
        (1.0, px, py, px * px, px * py, py * py, z, px * z, py * z, jnp.cos(psi), jnp.sin(psi)))]
    new = f._replace(psi=psi, **dict(zip(("w", "sx", "sy", "sxx", "sxy", "syy", "sz", "sxz", "syz", "sc", "ss"),
                                         sums)))

    ox, oy, r2, _ = solve(new)
    resultant = safe_div(safe_sqrt(new.sc * new.sc + new.ss * new.ss), new.w, eps=1e-12, fallback=1.0)
    good = (ok & (new.w > params.hard_iron_min_distance_m) & (r2 > 0.0)
            & (resultant < resultant_of_arc(deg(params.hard_iron_min_turn_deg)))
            & jnp.isfinite(ox) & jnp.isfinite(oy))
    X0 = jnp.where(good, params.X0 + ox, f.X0)
    Y0 = jnp.where(good, params.Y0 + oy, f.Y0)
    radius = jnp.where(good, safe_sqrt(r2), f.radius)
    moved2 = (X0 - f.X0) ** 2 + (Y0 - f.Y0) ** 2
    restart = good & (f.accepted < 0.5) & (moved2 > (params.hard_iron_restart_fraction * radius) ** 2)
    new = new._replace(X0=X0, Y0=Y0, radius=radius, accepted=jnp.where(good, 1.0, f.accepted))
    return HardIronState.pack(new), restart
