"""The identification loss: wrapped heading errors over a batch of drives, MAP priors, and the
unconstrained parameter space the optimiser works in.

Parameter space
---------------
The optimiser sees one flat vector ``z``, *whitened* so that the prior is N(0, I):

    u = u0 + s * z            (u: unconstrained value, u0: the starting file's value, s: prior std)
    theta = g(u)              g = sigmoid for P, curvature_clip and the fractions (kept in (0, 1)),
                              exp for lengths, gains and other positive constants,
                              c * softplus for a non-negative key (``a``, sigmas, gains) whose
                              start value is 0 (see below),
                              identity for signed quantities (compass offsets, rotation,
                              variation); the deviation table as the coefficients of a few
                              harmonics added to the start table (compass_fit, issue 14).

A start value of 0 is where users start for ``a`` (nobody measured it) and other non-negative keys
(``jaxmodel.params.NON_NEGATIVE_KEYS``), but it is the boundary of their range: no smooth map of
the whole line onto [0, inf) reaches 0 with a non-zero slope, so the optimiser could not leave it.
Such a key is fitted as theta = c softplus(u) with c its table default (1 when that is 0), u0 = 0:
the optimiser starts at c ln 2 (the table's order of magnitude), the fitted value stays
non-negative, and approaches 0 exponentially (like exp) if the data want it there.  Its prior std
in u is at least ``ZERO_START_PRIOR_STD`` (a start of 0 says nothing about the value).  A start
value > 0 keeps the log transform.

Whitening makes every coordinate O(1) (a metre of wheel base and 1e-4 s²/m² of ``a`` look the
same to the optimiser), the MAP prior is simply ½|z|², and the posterior std of z *is* the ratio
posterior std / prior std used for the identifiability warnings.

Loss
----
For each drive d with weights w_i (real sample, finite reference, wheel heading started):

    e_i   = wrap(psi_model_i - psi_ref_i)                    (SPEC §1: compare wrapped differences)
    r_i   = 2 sin(e_i / 2)          so  r_i² = 2 (1 - cos e_i), smooth at ±pi
    S_d   = sum_i w_i r_i² = 2 sum_i w_i (1 - cos e_i)
    D(theta) = sum_d (n_d / 2) log(S_d / W_d)                 (Gaussian likelihood, sigma_d profiled out)
    F(z)  = D(theta(z)) + ½ |z|²                              (MAP objective)

``n_d`` is the effective number of independent errors in drive d: its duration divided by the
increment window, or by ``decorrelation_s`` for absolute errors (heading errors at 10 Hz are far from
independent; see docs/identification.md).
Profiling sigma_d per drive weights each drive by its own error level, so a parking drive whose
errors are centimetres-small still counts, and the data/prior balance does not depend on units.

For the *odometer* heading (the wheel model alone) the heading is started from one compass
sample, whose error is a constant offset of the whole drive unrelated to the wheel parameters, and
wheel slip adds a slowly accumulating random walk.  ``identify`` therefore fits heading *changes*:
e_i <- wrap(e_i - e_prev_i), prev_i the last sample at least 30 s (or a travelled distance)
earlier (``increment_index``); the offset cancels and slip noise enters once per window.  The
alternative ``align=True`` profiles the offset out of absolute errors instead:
b_d = atan2(sum w sin e, sum w cos e), e_i <- wrap(e_i - b_d) (by the envelope theorem the gradient
is unchanged by the profiling), but lets the random walk leak into the parameters.

Which heading carries the signal of which parameter
---------------------------------------------------
* ``P, B, T_F, T_R, a`` act through eq. (8)/(14) on the wheel heading; ``T_C`` through the
  online refinement of ``a`` (eq. 13; only with ``refine_a`` and a consistent compass), which
  also changes the wheel heading; likewise the curvature window, dpp and calibration constants.
* ``D_N`` and the other heading-filter constants (FIG. 8C-8G) and the compass constants
  (FIG. 8A) act on the complementary heading; the wheel heading sees the compass only through its
  start value (it cancels in heading changes) and the refinement of ``a``.
``FILTER_KEYS`` lists the second group; ``identification.identify`` fits the first group on the
odometer heading and then the second on the complementary heading (mode ``odometer``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxmodel
from jaxmodel.angles import wrap
from jaxmodel.params import PARAMETER_SPECS

from .errors import OdoCompassError

DEFAULT_FIT = ("P", "B", "T_F", "a", "T_C", "D_N")

NOT_FITTABLE = ("sensor_axle", "counter_modulus")
"""Discrete keys: the axle is a choice and the counter modulus an integer property of the hardware."""

LOGIT_KEYS = {"P": (0.0, 1.0), "curvature_clip": (0.0, 1.0), "refine_compass_bad_fraction": (0.0, 1.0),
              "cal_no_compass_weight": (0.0, 1.0)}
"""Bounded keys, fitted through a sigmoid onto (lo, hi)."""

SIGNED_KEYS = ("variation_deg", "rotation_deg", "X0", "Y0", "deviation_deg")
"""Keys that may take any sign: fitted as they are (identity transform); the deviation table as the
coefficients of a few harmonics (transform 'harmonics', identification.compass_fit)."""

FILTER_KEYS = ("D_N", "wheel_error_K", "sdd_T", "heading_error_K", "K1", "K2", "F_update_distance_m",
               "map_threshold_deg", "compass_error_scale_deg", "compass_error_floor_deg", "reliability_scale_deg",
               "field_magnitude", "variation_deg", "rotation_deg", "X0", "Y0", "deviation_deg")
"""Keys whose effect on the heading goes through the compass and the complementary filter (FIG. 8A-8H);
in mode ``odometer`` they are fitted on the complementary heading with the wheel parameters fixed."""

PRIOR_STD: dict[str, float] = {
    # in unconstrained units: log-space for positive keys (0.05 = 5 %), logit for P, raw units for signed keys
    "P": 0.5,            # logit: P = 0.125 -> 68 % interval 0.08 .. 0.19
    "B": 0.05,           # a datasheet wheel base: 5 %
    "T_F": 0.05,
    "T_R": 0.05,
    "a": 0.7,            # velocity coefficient: known to a factor of 2
    "T_C": 1.0,          # refinement constant: a tuning value, known to a factor of e
    "D_N": 0.7,          # filter distance constant: a tuning value, known to a factor of 2
    "dpp_left": 0.02,
    "dpp_right": 0.02,
    "variation_deg": 5.0,
    "rotation_deg": 5.0,
    "X0": 2.0,
    "Y0": 2.0,
    "deviation_deg": 3.0,
    "curvature_clip": 1.0,
}
DEFAULT_PRIOR_STD_LOG = 0.5
DEFAULT_PRIOR_STD_SIGNED = 1.0

ZERO_START_PRIOR_STD = 2.0
"""Prior std (softplus units) of a non-negative key started at 0: theta within c x [0.13, 2.1] at one sigma."""

DEFAULT_DECORRELATION_S = 10.0
"""Assumed decorrelation time of the heading errors: a drive of T seconds counts as T / this
independent errors in the likelihood (standard errors scale with its square root)."""


def _from_unconstrained(key: str, transform: str, u, xp):
    """theta = g(u) for one fitted key (flat segment ``u``), with ``xp`` = numpy or jax.numpy.

    The sigmoid is jax.nn.sigmoid under jax (its gradient stays finite far out), the same formula
    in numpy."""
    if transform == "logit":
        lo, hi = LOGIT_KEYS[key]
        if xp is jnp:
            return lo + (hi - lo) * jax.nn.sigmoid(u)
        return lo + (hi - lo) / (1.0 + np.exp(-u))
    if transform == "log":
        return xp.exp(u)
    if transform == "softplus":
        if xp is jnp:
            return jax.nn.softplus(u)
        return np.logaddexp(0.0, u)
    return u


def _transform_of(key: str) -> str:
    if key == "deviation_deg":
        return "harmonics"
    if key in LOGIT_KEYS:
        return "logit"
    if key in SIGNED_KEYS:
        return "identity"
    return "log"


@dataclass(frozen=True)
class ParamSpace:
    """The whitened unconstrained coordinates z of the fitted keys (see the module docstring)."""

    keys: tuple[str, ...]
    transforms: tuple[str, ...]
    sizes: tuple[int, ...]
    u0: np.ndarray            # unconstrained start values (flat)
    s: np.ndarray             # prior std in unconstrained units (flat)
    labels: tuple[str, ...] = field(default=())  # one per coordinate: 'P', 'deviation_deg[cos2]', ...
    scale: np.ndarray | None = None  # theta = scale x g(u) (flat; None: 1), the softplus keys' c
    harmonics: tuple[int, ...] = ()  # orders of the deviation curve (transform 'harmonics', compass_fit)

    @property
    def dim(self) -> int:
        return int(self.u0.size)

    def _segments(self):
        """(key, transform, slice of the flat coordinates) for each fitted key, in order."""
        start = 0
        for key, tr, n in zip(self.keys, self.transforms, self.sizes):
            yield key, tr, slice(start, start + n)
            start += n

    def to_params(self, z, base):
        """Params equal to ``base`` except the fitted keys, set from z (traceable)."""
        u = jnp.asarray(self.u0) + jnp.asarray(self.s) * z
        values = {}
        for key, tr, sl in self._segments():
            if tr == "harmonics":  # the start table plus a few harmonics (compass_fit): theta = coefficients
                from .compass_fit import harmonic_basis

                basis = jnp.asarray(harmonic_basis(self.harmonics))
                values[key] = jnp.asarray(getattr(base, key)) + basis @ (u[sl] - jnp.asarray(self.u0[sl]))
                continue
            v = _from_unconstrained(key, tr, u[sl], jnp)
            if tr == "softplus":
                v = jnp.asarray(self._scale()[sl]) * v
            shape = np.shape(getattr(base, key))
            values[key] = v.reshape(shape) if shape else v[0]
        return base._replace(**values)

    def dtheta_dz(self, z) -> np.ndarray:
        """d theta / d z per coordinate (diagonal), for the delta-method standard errors."""
        u = self.u0 + self.s * np.asarray(z, dtype=np.float64)
        out = np.empty_like(u)
        for key, tr, sl in self._segments():
            seg = u[sl]
            if tr == "logit":
                lo, hi = LOGIT_KEYS[key]
                sg = 1.0 / (1.0 + np.exp(-seg))
                out[sl] = (hi - lo) * sg * (1.0 - sg)
            elif tr == "log":
                out[sl] = np.exp(seg)
            elif tr == "softplus":
                out[sl] = self._scale()[sl] / (1.0 + np.exp(-seg))
            else:
                out[sl] = 1.0
        return out * self.s

    def _scale(self) -> np.ndarray:
        return np.ones_like(self.u0) if self.scale is None else self.scale

    def theta(self, z) -> np.ndarray:
        """Fitted values (flat, physical units) at z."""
        u = self.u0 + self.s * np.asarray(z, dtype=np.float64)
        out = np.empty_like(u)
        for key, tr, sl in self._segments():
            out[sl] = _from_unconstrained(key, tr, u[sl], np)
            if tr == "softplus":
                out[sl] *= self._scale()[sl]
        return out


def parse_fit(fit: str | Sequence[str] | None) -> tuple[str, ...]:
    """The fit set from a comma list or a sequence; unknown or non-fittable keys raise OdoCompassError."""
    if fit is None:
        return DEFAULT_FIT
    if isinstance(fit, str):
        items = [k.strip() for k in fit.split(",") if k.strip()]
    else:
        items = [str(k).strip() for k in fit]
    if not items:
        raise OdoCompassError("--fit: empty parameter list")
    out: list[str] = []
    for k in items:
        if k not in PARAMETER_SPECS:
            raise OdoCompassError(f"--fit: unknown parameter key {k!r}")
        if k in NOT_FITTABLE:
            raise OdoCompassError(f"--fit: parameter {k!r} is discrete and cannot be fitted by gradient descent")
        if k not in out:
            out.append(k)
    return tuple(out)


def make_space(keys: Sequence[str], start, prior_std: Mapping[str, float] | None = None,
               all_keys: Sequence[str] | None = None) -> ParamSpace:
    """ParamSpace of ``keys`` around the start Params (the prior means).  ``all_keys`` (default
    ``keys``): the whole fit set, which decides the deviation curve's harmonics (compass_fit)."""
    from .compass_fit import deviation_harmonics, harmonic_labels, project

    orders = deviation_harmonics(tuple(all_keys) if all_keys is not None else tuple(keys))
    prior_std = dict(prior_std or {})
    for k in prior_std:
        if k not in PARAMETER_SPECS:
            raise OdoCompassError(f"prior_std: unknown parameter key {k!r}")
    from jaxmodel.params import NON_NEGATIVE_KEYS

    transforms, sizes, u0, s, labels, scales = [], [], [], [], [], []
    for key in keys:
        tr = _transform_of(key)
        v = np.asarray(getattr(start, key), dtype=np.float64).reshape(-1)
        c = np.ones_like(v)
        if tr == "log" and key in NON_NEGATIVE_KEYS and np.all(v == 0.0):
            tr = "softplus"  # the boundary start of a non-negative key (module docstring)
            default = float(np.max(np.abs(np.asarray(PARAMETER_SPECS[key].default, dtype=np.float64))))
            c = np.full_like(v, default if default > 0.0 else 1.0)
        if tr == "logit":
            lo, hi = LOGIT_KEYS[key]
            if not np.all((v > lo) & (v < hi)):
                raise OdoCompassError(f"cannot fit {key!r} from {float(v[0])}: the start value must lie strictly "
                                      f"inside ({lo:g}, {hi:g})")
            frac = (v - lo) / (hi - lo)
            uu = np.log(frac) - np.log1p(-frac)
        elif tr == "log":
            if not np.all(v > 0.0):
                what = "a non-negative parameter" if key in NON_NEGATIVE_KEYS else "a positive parameter"
                raise OdoCompassError(f"cannot fit {key!r} from {float(v[0])}: it is {what}, give a "
                                      f"{'non-negative' if key in NON_NEGATIVE_KEYS else 'positive'} start value")
            uu = np.log(v)
        elif tr == "softplus":
            uu = np.zeros_like(v)
        elif tr == "harmonics":
            uu = project(v, orders)
            c = np.ones_like(uu)
        else:
            uu = v.copy()
        default = DEFAULT_PRIOR_STD_SIGNED if tr in ("identity", "harmonics") else DEFAULT_PRIOR_STD_LOG
        sd = float(prior_std.get(key, PRIOR_STD.get(key, default)))
        if tr == "softplus" and key not in prior_std:
            sd = max(sd, ZERO_START_PRIOR_STD)
        if not sd > 0.0:
            raise OdoCompassError(f"prior_std of {key!r} must be positive, got {sd}")
        transforms.append(tr)
        sizes.append(uu.size)
        u0.append(uu)
        s.append(np.full(uu.size, sd))
        scales.append(c)
        if tr == "harmonics":
            labels.extend(harmonic_labels(key, orders))
        else:
            labels.extend([key] if v.size == 1 else [f"{key}[{j}]" for j in range(v.size)])
    return ParamSpace(tuple(keys), tuple(transforms), tuple(sizes), np.concatenate(u0), np.concatenate(s),
                      tuple(labels), np.concatenate(scales), orders if "deviation_deg" in keys else ())


# ----------------------------------------------------------------------------------------------
# forward model over a batch


def batch_outputs(params, inputs, config, fields: Sequence[str], checkpoint: bool = False):
    """Run the estimator over a batch of drives (leading axis) and return the chosen Outputs
    fields plus the ``initialized`` flag (1.0 once the wheel heading has been started), each
    (batch, N).  ``checkpoint`` rematerializes each step in the backward pass (reverse mode)."""
    table = None
    if config.track == "table":
        from jaxmodel import track as _track

        table = _track.effective_track_table(params.P, params.B, params.T_F, params.curvature_clip)

    def body(state, sample):
        new, out = jaxmodel.step(params, state, sample, config, table)
        return new, tuple(getattr(out, f) for f in fields) + (new.initialized,)

    if checkpoint:
        body = jax.checkpoint(body)

    def one(inp):
        return jax.lax.scan(body, jaxmodel.init_state(params), inp)[1]

    return jax.vmap(one)(inputs)


def heading_errors(params, inputs, ref, mask, config, field_name: str, checkpoint: bool = False):
    """(e, w): wrapped errors of ``field_name`` against ``ref`` and their weights, each (batch, N).
    w = mask x (wheel heading started); no gradient flows through w."""
    h, started = batch_outputs(params, inputs, config, (field_name,), checkpoint)
    e = wrap(h - ref)
    w = jax.lax.stop_gradient(mask * (started > 0.5))
    return e, w


def _circular_offset(e, w):
    """Per-drive weighted circular mean of e (batch,), 0 for a drive without weight (NaN-safe)."""
    c = jnp.sum(w * jnp.cos(e), axis=-1)
    s = jnp.sum(w * jnp.sin(e), axis=-1)
    ok = (c * c + s * s) > 1e-30
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, s, 0.0), jnp.where(ok, c, 1.0)), 0.0)


def residuals(e, w, align: bool, lag: int = 0, prev=None, sample_weight=None):
    """(r, w'): r = 2 sin(e'/2) (r² = 2(1 - cos e')) and its weights.

    ``prev`` (int array like e, -1 = none): e' is the error of the heading *change* since sample
    prev_i, wrap(e_i - e_prev_i), weighted where both ends are (times ``sample_weight``); ``lag``
    > 0 is the same with prev_i = i - lag.  Otherwise e' = e, minus the per-drive circular mean
    when ``align``."""
    if lag > 0 and prev is None:
        prev = jnp.broadcast_to(jnp.arange(e.shape[-1]) - lag, e.shape)
    if prev is not None:
        prev = jnp.asarray(prev)
        idx = jnp.clip(prev, 0, None)
        e_prev = jnp.take_along_axis(e, idx, axis=-1)
        w_prev = jnp.take_along_axis(w, idx, axis=-1)
        w = w * w_prev * (prev >= 0)
        if sample_weight is not None:
            w = w * sample_weight
        return 2.0 * jnp.sin(0.5 * wrap(e - e_prev)), w
    if align:
        e = wrap(e - _circular_offset(e, w)[:, None])
    return 2.0 * jnp.sin(0.5 * e), w


def travelled_distance(inputs, params) -> np.ndarray:
    """Cumulative |AD| (m) per drive from the pulse counters (counter wrap decoded), numpy (batch, N)."""
    from .drive_log import counter_increments

    mod = float(params.counter_modulus)

    def inc(x):
        d = counter_increments(x, mod)
        return np.where(np.isfinite(d), d, 0.0)

    ad = 0.5 * (inc(inputs.left_pulses) * float(params.dpp_left) + inc(inputs.right_pulses) * float(params.dpp_right))
    return np.cumsum(np.abs(ad), axis=-1)


def increment_index(coord: np.ndarray, span: float) -> np.ndarray:
    """For each sample i the last sample j with coord_j <= coord_i - span (-1 if none), per drive."""
    coord = np.asarray(coord, dtype=np.float64)
    out = np.empty(coord.shape, dtype=np.int64)
    for b in range(coord.shape[0]):
        c = np.maximum.accumulate(coord[b])
        out[b] = np.searchsorted(c, c - span, side="right") - 1
    return out


def data_term(r, w, n_eff):
    """D = sum_d (n_d/2) log(S_d/W_d): Gaussian likelihood with each drive's sigma profiled out."""
    s_d = jnp.sum(w * r * r, axis=-1)
    w_d = jnp.sum(w, axis=-1)
    has = w_d > 0.0
    ratio = jnp.where(has, s_d / jnp.where(has, w_d, 1.0), 1.0)
    return jnp.sum(jnp.where(has, 0.5 * n_eff * jnp.log(ratio + 1e-30), 0.0))


def effective_counts(time_s: np.ndarray, weights: np.ndarray, decorrelation_s: float) -> np.ndarray:
    """n_d = (weighted duration of drive d) / decorrelation_s, at least 1 for a drive with data."""
    t = np.asarray(time_s, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    dt = np.diff(t, axis=-1, prepend=t[..., :1])
    dt = np.clip(dt, 0.0, 10.0 * np.median(dt[dt > 0]) if np.any(dt > 0) else 1.0)
    n = np.sum(w * dt, axis=-1) / float(decorrelation_s)
    return np.where(np.sum(w, axis=-1) > 0, np.maximum(n, 1.0), 0.0)


@dataclass
class StageProblem:
    """One fitting stage: which keys, which heading, which estimator configuration."""

    space: ParamSpace
    base: object              # Params holding every non-fitted value
    inputs: object            # jaxmodel.Inputs, (batch, N) arrays
    ref: np.ndarray           # (batch, N) rad
    mask: np.ndarray          # (batch, N)
    config: object            # jaxmodel.Config
    field_name: str           # 'wheel_heading' or 'heading'
    align: bool               # profile out a per-drive constant offset
    n_eff: np.ndarray | None = None  # (batch,)
    lag: int = 0              # > 0: fit heading changes over this many samples instead
    prev: np.ndarray | None = None           # or since these samples (increment_index)
    sample_weight: np.ndarray | None = None  # extra per-sample weights of those changes

    def objective(self, z, checkpoint: bool = False):
        """F(z) = D + ½|z|² (scalar); for reverse-mode differentiation."""
        p = self.space.to_params(z, self.base)
        e, w = heading_errors(p, self.inputs, self.ref, self.mask, self.config, self.field_name, checkpoint)
        r, w = residuals(e, w, self.align, self.lag, self.prev, self.sample_weight)
        return data_term(r, w, jnp.asarray(self.n_eff)) + 0.5 * jnp.sum(z * z)

    def residual_fn(self, z):
        """(r, (w, e)) for forward-mode Jacobians."""
        p = self.space.to_params(z, self.base)
        e, w = heading_errors(p, self.inputs, self.ref, self.mask, self.config, self.field_name)
        r, w = residuals(e, w, self.align, self.lag, self.prev, self.sample_weight)
        return r, (w, e)


def forward_value_grad_gn(problem: StageProblem):
    """A jitted z -> (F, grad F, GN Hessian of F, per-drive S_d/W_d) using forward-mode derivatives.

    The residual Jacobian J (dim x batch x N) comes from one ``vmap`` of ``jax.jvp`` over the
    basis of z: the primal is computed once, the tangents ride along as a small extra batch
    axis, and no per-step residuals are stored (the reason reverse mode is slow on XLA:CPU).
    grad F = sum_d (n_d/S_d) sum_i w r J + z, and the Gauss-Newton Hessian
    H = sum_d (n_d/S_d) J^T W J + I (the curvature of log S_d is dropped, as in Gauss-Newton).
    """
    dim = problem.space.dim
    n_eff = jnp.asarray(problem.n_eff)

    def fn(z):
        def jvp_one(v):
            (r, aux), (jr, _) = jax.jvp(problem.residual_fn, (z,), (v,))
            return r, aux, jr

        r, (w, e), J = jax.vmap(jvp_one, out_axes=(None, None, 0))(jnp.eye(dim, dtype=z.dtype))
        s_d = jnp.sum(w * r * r, axis=-1)
        w_d = jnp.sum(w, axis=-1)
        has = w_d > 0.0
        scale = jnp.where(has, n_eff / jnp.where(has, s_d + 1e-30 * w_d, 1.0), 0.0)  # n_d / S_d
        value = data_term(r, w, n_eff) + 0.5 * jnp.sum(z * z)
        wr = (scale[:, None] * w * r)
        grad = jnp.einsum("kbn,bn->k", J, wr) + z
        sw = jnp.sqrt(scale[:, None] * w)
        Jw = J * sw[None]
        hess = jnp.einsum("kbn,lbn->kl", Jw, Jw) + jnp.eye(dim, dtype=z.dtype)
        ms = jnp.where(has, s_d / jnp.where(has, w_d, 1.0), 0.0)
        return value, grad, hess, ms

    return jax.jit(fn)


def reverse_value_grad(problem: StageProblem, checkpoint: bool = True):
    """A jitted z -> (F, grad F) by reverse mode (``jax.checkpoint`` on each step by default)."""
    return jax.jit(jax.value_and_grad(lambda z: problem.objective(z, checkpoint)))
