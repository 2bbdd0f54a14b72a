"""fmu/jaxpr_lower.py: the jaxpr -> Python / C lowering behind the FMU's fast engines.

Each primitive the estimator uses is checked against XLA (``jax.jit``) on edge values (signed
zeros, halves, huge values, infinities, NaN, division by zero, out-of-domain arguments): bit for
bit for IEEE-exact operations, within a few ulp for the elementary functions, NaN where XLA gives
NaN.  The Python and C dialects agree bit for bit with each other.
"""

from __future__ import annotations

import ctypes
import subprocess

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

from fmu import jaxpr_lower as jl
from fmu.build import C_FLAGS, _compiler
from jaxmodel.packed import value_once

# No subnormal numbers: XLA:CPU flushes them to zero, the lowered code keeps IEEE gradual underflow.
EDGE = np.array([0.0, -0.0, 0.5, -0.5, 1.5, -2.5, 2.5, 3.0, -7.25, 1e-300, 1e308, -1e308, 710.0, -745.5,
                 np.inf, -np.inf, np.nan, 0.1, 123.456, -3e15, 4.6e15, 1e300])
OTHER = np.array([2.0, 0.0, -0.0, 0.5, -1.5, 3.0, np.inf, np.nan, -np.inf, 1e-300, 7.0, -2.0, 1e10, 0.25,
                  1.0, -1.0, 2.0, 0.0, -4.5, 1e16, 3.0, 1e-8])

EXACT = {
    "add": lambda x, y: x + y, "sub": lambda x, y: x - y, "mul": lambda x, y: x * y, "div": lambda x, y: x / y,
    "neg_abs": lambda x, y: -jnp.abs(x), "floor": lambda x, y: jnp.floor(x), "ceil": lambda x, y: jnp.ceil(x),
    "round_even": lambda x, y: jnp.round(x),
    "round_away": lambda x, y: lax.round(x, lax.RoundingMethod.AWAY_FROM_ZERO),
    "sqrt": lambda x, y: jnp.sqrt(x), "max": lambda x, y: jnp.maximum(x, y), "min": lambda x, y: jnp.minimum(x, y),
    "rem": lambda x, y: lax.rem(x, y), "sign": lambda x, y: jnp.sign(x), "square": lambda x, y: x * x,
    "pow2": lambda x, y: x ** 2, "pow3": lambda x, y: x ** 3, "pow_m2": lambda x, y: x ** -2,
    "where": lambda x, y: jnp.where(x > y, x, y), "isfinite": lambda x, y: jnp.where(jnp.isfinite(x), 1.0, 0.0),
    "clip": lambda x, y: jnp.clip(x, -1.0, 2.0), "logic": lambda x, y: jnp.where((x > 0) & ~(y < 0) | (x == y), 1., 2.),
    "f2i": lambda x, y: jnp.clip(x, -1e12, 1e12).astype(jnp.int32).astype(jnp.float64),
    "mod": lambda x, y: jnp.mod(x, 3.0),
    # the bits as int64 and back (jaxmodel.packed.value_once): the next float away from zero; the maximum with the
    # smallest int64 (a literal C cannot write as such); the round trip, folded away
    "bits_next": lambda x, y: lax.bitcast_convert_type(lax.bitcast_convert_type(x, jnp.int64) + 1, jnp.float64),
    "bits_max": lambda x, y: lax.bitcast_convert_type(
        jnp.maximum(lax.bitcast_convert_type(x, jnp.int64), jnp.int64(-(2**63))), jnp.float64),
    "value_once": lambda x, y: value_once(x),
}
TRANSCENDENTAL = {
    "exp": lambda x, y: jnp.exp(x), "log": lambda x, y: jnp.log(x), "sin": lambda x, y: jnp.sin(x),
    "cos": lambda x, y: jnp.cos(x), "atan2": lambda x, y: jnp.arctan2(x, y), "tanh": lambda x, y: jnp.tanh(x),
    "log1p": lambda x, y: jnp.log1p(x), "expm1": lambda x, y: jnp.expm1(x),
}


def _ulps(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    same_nan = np.isnan(a) & np.isnan(b)
    same = (a == b) | same_nan
    ia = a.view(np.int64).astype(object)
    ib = b.view(np.int64).astype(object)
    d = np.array([0 if s else (abs(int(x) - int(y)) if (x >= 0) == (y >= 0) else 2**63) for x, y, s in zip(ia, ib, same)])
    return d


def _compile_c(tmp_path, program, name="fn"):
    cc = _compiler()
    if cc is None:
        pytest.skip("no C compiler")
    src = tmp_path / f"{name}.c"
    lib = tmp_path / f"{name}.so"
    src.write_text(jl.C_PRELUDE + program.to_c(name))
    proc = subprocess.run([cc, *C_FLAGS, "-o", str(lib), str(src), "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return getattr(ctypes.CDLL(str(lib)), name)


def _call_c(fn, ins, out_sizes):
    dbl = ctypes.c_double
    arrays = [(dbl * len(a))(*a) for a in ins]
    outs = [(dbl * n)() for n in out_sizes]
    fn(*arrays, *outs)
    return [np.array(o[:]) for o in outs]


@pytest.mark.parametrize("table", ["exact", "transcendental"])
def test_elementwise_primitives_match_xla(tmp_path, table):
    ops = EXACT if table == "exact" else TRANSCENDENTAL

    def fn(x, y):
        return tuple(op(x, y) for op in ops.values())

    with jax.enable_x64(True):
        x, y = jnp.asarray(EDGE, jnp.float64), jnp.asarray(OTHER, jnp.float64)
        closed = jax.make_jaxpr(fn)(x, y)
        want = [np.asarray(w) for w in jax.jit(fn)(x, y)]
    program = jl.lower_program(closed, [None, None])
    py = program.to_python("fn").fn(EDGE.tolist(), OTHER.tolist())
    c = _call_c(_compile_c(tmp_path, program), [EDGE.tolist(), OTHER.tolist()], [len(EDGE)] * len(ops))
    for k, name in enumerate(ops):
        got_py, got_c = np.asarray(py[k], np.float64), c[k]
        real = ~np.isnan(got_py)  # (the sign of a NaN carries no meaning)
        assert np.array_equal(got_py, got_c, equal_nan=True) and \
            np.array_equal(np.signbit(got_py[real]), np.signbit(got_c[real])), f"{name}: Python and C dialects differ"
        assert np.array_equal(np.isnan(got_py), np.isnan(want[k])), f"{name}: NaN where XLA has none (or v.v.)"
        tol = 0 if table == "exact" else 4
        worst = int(_ulps(got_py, want[k]).max())
        assert worst <= tol, f"{name}: {worst} ulp from XLA\n{EDGE}\n{got_py}\n{want[k]}"


def test_structural_primitives_match_xla(tmp_path):
    table = jnp.linspace(-3.0, 4.0, 36)

    def fn(x, m):
        i = jnp.mod(jnp.floor(x[0] * 7.0), 36.0).astype(jnp.int32)
        looked = table[i] + table[(i + 1) % 36]                       # dynamic_slice with a data-dependent index
        v = jnp.zeros(5).at[2].set(x[1]).at[4].add(x[2])             # scatter, scatter-add
        mat = m.reshape(3, 3)
        quad = x[:3] @ mat @ x[:3] + jnp.trace(mat @ mat.T)           # dot_general, transpose
        stacked = jnp.stack([x[0], x[1], x[2]]).sum()                 # stack, reduce_sum
        padded = jnp.pad(x[:2], (1, 2), constant_values=0.5)          # pad
        cond = lax.cond(x[0] > 0.0, lambda z: z * 2.0, lambda z: z - 1.0, x[1])
        def body(c, xs):
            return c + xs, c * xs
        carry, ys = lax.scan(body, x[0], x[:4])                       # scan (unrolled)
        return jnp.concatenate([jnp.atleast_1d(looked), v, jnp.atleast_1d(quad), jnp.atleast_1d(stacked), padded,
                                jnp.atleast_1d(cond), jnp.atleast_1d(carry), ys])

    rng = np.random.default_rng(0)
    for trial in range(5):
        x = rng.normal(size=6) * 3.0
        m = rng.normal(size=9)
        with jax.enable_x64(True):
            closed = jax.make_jaxpr(fn)(jnp.asarray(x), jnp.asarray(m))
            want = np.asarray(jax.jit(fn)(jnp.asarray(x), jnp.asarray(m)))
        program = jl.lower_program(closed, [None, None])
        got = np.asarray(program.to_python("fn").fn(x.tolist(), m.tolist())[0])
        np.testing.assert_allclose(got, want, rtol=1e-15, atol=1e-15)
        if trial == 0:
            cfn = _compile_c(tmp_path, program)
        got_c = _call_c(cfn, [x.tolist(), m.tolist()], [want.size])[0]
        assert np.array_equal(got, got_c)


def test_parameters_fold_into_constants():
    def fn(p, x):
        return jnp.sin(p[0]) * x + jnp.sqrt(p[1]) / (1.0 + p[0] ** 2)

    with jax.enable_x64(True):
        closed = jax.make_jaxpr(fn)(jnp.zeros(2), jnp.zeros(3))
    folded = jl.lower_program(closed, [np.array([0.3, 2.0]), None])
    free = jl.lower_program(closed, [None, None])
    assert folded.n_ops < free.n_ops
    x = [1.0, -2.0, 0.5]
    a = folded.to_python().fn(x)[0]
    b = free.to_python().fn([0.3, 2.0], x)[0]
    assert a == b


def test_bitcast_round_trip_folds_away():
    with jax.enable_x64(True):
        closed = jax.make_jaxpr(lambda x: value_once(x) * 2.0)(jnp.zeros(3))
    program = jl.lower_program(closed, [None])
    c_text = program.to_c("fn")
    assert "bits" not in c_text, c_text
    got = np.asarray(program.to_python("fn").fn([1.5, -0.0, 5e-324])[0], np.float64)
    assert np.array_equal(got.view(np.int64), np.array([3.0, -0.0, 1e-323]).view(np.int64))


def test_unsupported_primitive_is_reported():
    def fn(x):
        return lax.while_loop(lambda c: c[0] < 10.0, lambda c: (c[0] + 1.0, c[1] * 2.0), (x[0], x[1]))[1]

    with jax.enable_x64(True):
        closed = jax.make_jaxpr(fn)(jnp.zeros(2))
    with pytest.raises(jl.Unsupported, match="while"):
        jl.lower_program(closed, [None])


def test_estimator_step_engines_agree_bit_for_bit(tmp_path):
    """The Python lowering (parameters folded) and the C build (parameters as arguments) of the
    estimator's step give identical bits, and agree with jaxmodel.run."""
    import jaxmodel
    from fmu.build import check_drive
    from fmu.engine import Engine, config_key

    eng = Engine(tmp_path, "test")
    eng._jax, eng._jm, eng._lower = jax, jaxmodel, jl  # the repo's jaxmodel instead of a bundle
    params, cfg = eng.make({}, {})
    source, meta = eng.native_source(params, cfg)
    cc = _compiler()
    if cc is None:
        pytest.skip("no C compiler")
    (tmp_path / "native").mkdir()
    (tmp_path / "native" / "s.c").write_text(source)
    proc = subprocess.run([cc, *C_FLAGS, "-o", str(tmp_path / "native" / "s.so"), str(tmp_path / "native" / "s.c"),
                           "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    native = eng.prepare({}, {}, "native", tmp_path, [dict(meta, file="native/s.so")])
    python = eng.prepare({}, {}, "python")
    assert native.kind == "native" and python.kind == "python" and meta["key"] == config_key(cfg)
    d = check_drive(600)
    rows = np.stack([d[f] for f in jaxmodel.Inputs._fields], axis=1).tolist()
    sn, sp = native.s0, python.s0
    assert sn == sp
    on, op = [], []
    for r in rows:
        sn, o1 = native.step(sn, r)
        sp, o2 = python.step(sp, r)
        on.append(o1)
        op.append(o2)
    assert np.array_equal(np.asarray(on), np.asarray(op), equal_nan=True) and list(sn) == list(sp)
    with jax.enable_x64(True):
        ref = jaxmodel.run(params, jaxmodel.Inputs(*[jnp.asarray(d[f][:600]) for f in jaxmodel.Inputs._fields]))
    np.testing.assert_allclose(np.asarray(on)[:, 0], np.asarray(ref.heading), rtol=0, atol=1e-12)
