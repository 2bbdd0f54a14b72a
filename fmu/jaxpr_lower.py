"""Lower a traced JAX computation (a closed jaxpr) to straight-line Python scalar code.

Why: the FMU must answer one ``doStep`` per sensor sample.  A jitted XLA call of the
estimator step costs ~60-100 µs on this CPU (XLA:CPU runs each of the ~80 fusions of the
step as a separate kernel), which caps the FMU far below 10,000 steps/s.  This module
takes the jaxpr that JAX traces from ``jaxmodel.run_from`` -- the estimator's own
equations, nothing re-written by hand -- and emits equivalent Python code on floats:

* every array of the (static-shaped) jaxpr is scalarised into one Python local per element,
  so reshapes, slices, concatenations and the ravel/unravel of the state cost nothing;
* operands known at lowering time (the FMU's fixed parameters) are folded, evaluated with
  the very templates the generated code uses, so folding never changes a result;
* common subexpressions are shared and dead code is dropped.

The primitives' semantics follow XLA's IEEE float64 behaviour (no Python exception for a
division by zero, the square root of a negative number, an overflowing ``exp``, ...).
Elementary functions come from the C library via ``math`` and may differ from XLA's own
approximations in the last bit; the FMU tests compare the two engines and ``jaxmodel.run``.

Anything not covered (an unknown primitive, a data-dependent loop, a non-float64 float type)
raises :class:`Unsupported`; the caller then falls back to the XLA executable.

This file is self-contained (it imports neither jax nor the project) so that the FMU can
bundle it; it reads jaxpr objects only through their public attributes.
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

__all__ = ["Unsupported", "Lowered", "lower_jaxpr", "RUNTIME"]


class Unsupported(Exception):
    """The jaxpr uses something this lowering does not translate (the caller falls back to XLA)."""


# ----------------------------------------------------------------------------------------------
# Runtime helpers: the namespace of the generated code.  Each reproduces XLA's float64 result
# (IEEE 754) where Python's would raise or differ.
# ----------------------------------------------------------------------------------------------
_nan = float("nan")
_inf = float("inf")
_isfinite = math.isfinite
_copysign = math.copysign
_msqrt = math.sqrt
_mfloor = math.floor
_mceil = math.ceil


def _div(a, b):
    """IEEE a / b for float64 (Python raises ZeroDivisionError)."""
    if b:
        return a / b
    if a != a or a == 0.0:
        return _nan
    return _copysign(_inf, a) * _copysign(1.0, b)


def _idiv(a, b):
    """XLA integer division: truncation toward zero; division by zero gives -1."""
    if b == 0:
        return -1
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def _irem(a, b):
    if b == 0:
        return a
    r = abs(a) % abs(b)
    return r if a >= 0 else -r


def _rem(a, b):
    """XLA rem on floats = C fmod (sign of the dividend)."""
    try:
        return math.fmod(a, b)
    except ValueError:
        return _nan


def _floor(x):
    try:
        return float(math.floor(x)) or x * 0.0
    except (ValueError, OverflowError):
        return x


def _ceil(x):
    try:
        return float(math.ceil(x)) or x * 0.0
    except (ValueError, OverflowError):
        return x


def _round_even(x):
    try:
        return float(round(x)) or x * 0.0
    except (ValueError, OverflowError):
        return x


def _round_away(x):
    if not _isfinite(x):
        return x
    a = abs(x)
    r = math.floor(a)
    if a - r >= 0.5:
        r += 1
    return _copysign(float(r), x)


def _exp(x):
    try:
        return math.exp(x)
    except OverflowError:
        return _inf


def _exp2(x):
    try:
        return math.pow(2.0, x)
    except OverflowError:
        return _inf


def _expm1(x):
    try:
        return math.expm1(x)
    except OverflowError:
        return _inf


def _log(x):
    if x > 0.0:
        return math.log(x)
    if x == 0.0:
        return -_inf
    return _nan


def _log1p(x):
    if x > -1.0:
        return math.log1p(x)
    if x == -1.0:
        return -_inf
    return _nan


def _sin(x):
    return math.sin(x) if _isfinite(x) else _nan


def _cos(x):
    return math.cos(x) if _isfinite(x) else _nan


def _tan(x):
    return math.tan(x) if _isfinite(x) else _nan


def _asin(x):
    return math.asin(x) if -1.0 <= x <= 1.0 else _nan


def _acos(x):
    return math.acos(x) if -1.0 <= x <= 1.0 else _nan


def _sinh(x):
    try:
        return math.sinh(x)
    except OverflowError:
        return _copysign(_inf, x)


def _cosh(x):
    try:
        return math.cosh(x)
    except OverflowError:
        return _inf


def _logistic(x):
    if x >= 0.0:
        return 1.0 / (1.0 + _exp(-x))
    e = _exp(x)
    return e / (1.0 + e)


def _pow(a, b):
    try:
        r = math.pow(a, b)
    except ValueError:
        return _nan
    except OverflowError:
        return _inf if (a > 0.0 or float(b).is_integer() and int(b) % 2 == 0) else -_inf
    return r


def _sign(x):
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x  # +-0 and NaN keep themselves


def _isign(x):
    return (x > 0) - (x < 0)


def _f2i(x, lo=-(2**31), hi=2**31 - 1):
    """XLA float -> int conversion: truncation toward zero, NaN -> 0, saturating."""
    if x != x:
        return 0
    if x >= hi:
        return hi
    if x <= lo:
        return lo
    return int(x)


def _fmax(a, b):
    return a if (a >= b or a != a) else b


def _fmin(a, b):
    return a if (a <= b or a != a) else b


def _clampi(i, lo, hi):
    return lo if i < lo else (hi if i > hi else i)


RUNTIME: dict[str, Any] = {
    name: obj for name, obj in dict(globals()).items()
    if name.startswith("_") and not name.startswith("__") and (callable(obj) or isinstance(obj, float))
}
RUNTIME["math"] = math


# ----------------------------------------------------------------------------------------------
# Atoms: a value of the jaxpr is a numpy object array (its shape) of atoms; an atom is a Python
# constant (float/int/bool) or a Ref to a local of the generated code.
# ----------------------------------------------------------------------------------------------
class Ref:
    __slots__ = ("name",)

    def __init__(self, name: str):
        self.name = name

    def __repr__(self) -> str:  # pragma: no cover - debugging aid
        return self.name


def _kind(dtype) -> str:
    dt = np.dtype(dtype)
    if dt == np.bool_:
        return "bool"
    if np.issubdtype(dt, np.integer):
        return "int"
    if dt == np.float64:
        return "float"
    raise Unsupported(f"dtype {dt} (only float64, integers and bool are lowered)")


def _py(value, kind: str):
    if kind == "float":
        return float(value)
    if kind == "int":
        return int(value)
    return bool(value)


def _lit(atom) -> str:
    if isinstance(atom, Ref):
        return atom.name
    if isinstance(atom, bool):
        return "True" if atom else "False"
    if isinstance(atom, int):
        return repr(atom) if atom >= 0 else f"({atom!r})"
    if isinstance(atom, float):
        if atom != atom:
            return "_nan"
        if atom in (_inf, -_inf):
            return "_inf" if atom > 0 else "(-_inf)"
        text = repr(atom)
        return f"({text})" if text.startswith("-") else text
    raise Unsupported(f"constant of type {type(atom).__name__}")


def _objarray(shape, atoms=None) -> np.ndarray:
    arr = np.empty(shape, dtype=object)
    if atoms is not None:
        flat = arr.reshape(-1)
        for i, a in enumerate(atoms):
            flat[i] = a
    return arr


def _const_array(value, kind: str) -> np.ndarray:
    value = np.asarray(value)
    arr = np.empty(value.shape, dtype=object)
    flat_in = value.reshape(-1)
    flat = arr.reshape(-1)
    for i in range(flat_in.size):
        flat[i] = _py(flat_in[i], kind)
    return arr


class Tpl(NamedTuple):
    """An operation in both dialects: Python source and C source, operands as {0}, {1}, ..."""

    py: str
    c: str


def T(py: str, c: str | None = None) -> Tpl:
    return Tpl(py, py if c is None else c)


IDENTITY = T("{0}")

# Elementwise templates by input kind.  Python: the helpers above reproduce IEEE float64 where
# Python would raise; C: <math.h> is IEEE already (compiled without fast-math and FMA contraction).
_FLOAT_UNARY = {
    "neg": T("(-{0})"), "abs": T("abs({0})", "fabs({0})"), "sign": T("_sign({0})", "odc_sign({0})"),
    # |x| >= 2**52 is already integral; NaN and +-inf fail the comparison and pass through
    # (... or x * 0.0): a zero result keeps the sign of x, as IEEE floor/ceil/rint do
    "floor": T("((float(_mfloor({0})) or {0} * 0.0) if -4.5e15 < {0} < 4.5e15 else {0})", "floor({0})"),
    "ceil": T("((float(_mceil({0})) or {0} * 0.0) if -4.5e15 < {0} < 4.5e15 else {0})", "ceil({0})"),
    "is_finite": T("({0} - {0} == 0.0)", "(isfinite({0}) != 0)"), "exp": T("_exp({0})", "exp({0})"),
    "exp2": T("_exp2({0})", "exp2({0})"), "expm1": T("_expm1({0})", "expm1({0})"),
    "log": T("_log({0})", "log({0})"), "log1p": T("_log1p({0})", "log1p({0})"),
    "sin": T("_sin({0})", "sin({0})"), "cos": T("_cos({0})", "cos({0})"), "tan": T("_tan({0})", "tan({0})"),
    "asin": T("_asin({0})", "asin({0})"), "acos": T("_acos({0})", "acos({0})"), "atan": T("math.atan({0})", "atan({0})"),
    "sinh": T("_sinh({0})", "sinh({0})"), "cosh": T("_cosh({0})", "cosh({0})"), "tanh": T("math.tanh({0})", "tanh({0})"),
    "logistic": T("_logistic({0})", "odc_logistic({0})"),
    "sqrt": T("(_msqrt({0}) if {0} >= 0.0 else _nan)", "sqrt({0})"), "square": T("({0} * {0})"),
    "rsqrt": T("(_div(1.0, _msqrt({0})) if {0} >= 0.0 else _nan)", "(1.0 / sqrt({0}))"),
    "erf": T("math.erf({0})", "erf({0})"), "lgamma": T("math.lgamma({0})", "lgamma({0})"),
    "copy": IDENTITY, "copy_p": IDENTITY, "optimization_barrier": IDENTITY, "real": IDENTITY,
}
_FLOAT_DIV = T("({0} / {1} if {1} else _div({0}, {1}))", "({0} / {1})")
_FLOAT_DIV_NONZERO = T("({0} / {1})")
_FLOAT_MAX = T("({0} if ({0} >= {1} or {0} != {0}) else {1})", "((({0} >= {1}) || ({0} != {0})) ? {0} : {1})")
_FLOAT_MIN = T("({0} if ({0} <= {1} or {0} != {0}) else {1})", "((({0} <= {1}) || ({0} != {0})) ? {0} : {1})")
_FLOAT_BINARY = {
    "add": T("({0} + {1})"), "sub": T("({0} - {1})"), "mul": T("({0} * {1})"),
    "div": _FLOAT_DIV, "rem": T("_rem({0}, {1})", "fmod({0}, {1})"), "pow": T("_pow({0}, {1})", "pow({0}, {1})"),
    "max": _FLOAT_MAX, "min": _FLOAT_MIN,
    "atan2": T("math.atan2({0}, {1})", "atan2({0}, {1})"), "nextafter": T("math.nextafter({0}, {1})", "nextafter({0}, {1})"),
}
_INT_MAX = T("({0} if {0} >= {1} else {1})", "(({0} >= {1}) ? {0} : {1})")
_INT_MIN = T("({0} if {0} <= {1} else {1})", "(({0} <= {1}) ? {0} : {1})")
_INT_UNARY = {"neg": T("(-{0})"), "abs": T("abs({0})", "llabs({0})"), "sign": T("_isign({0})", "odc_isign({0})"),
              "not": T("(~{0})"), "copy": IDENTITY, "copy_p": IDENTITY, "optimization_barrier": IDENTITY}
_INT_BINARY = {
    "add": T("({0} + {1})"), "sub": T("({0} - {1})"), "mul": T("({0} * {1})"),
    "div": T("_idiv({0}, {1})", "odc_idiv({0}, {1})"), "rem": T("_irem({0}, {1})", "odc_irem({0}, {1})"),
    "max": _INT_MAX, "min": _INT_MIN, "and": T("({0} & {1})"), "or": T("({0} | {1})"), "xor": T("({0} ^ {1})"),
}
_BOOL_AND = T("({0} and {1})", "({0} && {1})")
_BOOL_OR = T("({0} or {1})", "({0} || {1})")
_BOOL_UNARY = {"not": T("(not {0})", "(!{0})"), "copy": IDENTITY, "copy_p": IDENTITY, "optimization_barrier": IDENTITY}
_BOOL_BINARY = {"and": _BOOL_AND, "or": _BOOL_OR, "xor": T("({0} != {1})"),
                "eq": T("({0} == {1})"), "ne": T("({0} != {1})")}
_COMPARE = {"eq": T("({0} == {1})"), "ne": T("({0} != {1})"), "lt": T("({0} < {1})"), "le": T("({0} <= {1})"),
            "gt": T("({0} > {1})"), "ge": T("({0} >= {1})")}
_SELECT2 = T("({2} if {0} else {1})", "({0} ? {2} : {1})")
_CONVERT = {
    ("float", "float"): IDENTITY, ("int", "int"): IDENTITY, ("bool", "bool"): IDENTITY,
    ("float", "int"): T("_f2i({0})", "odc_f2i({0})"), ("float", "bool"): T("({0} != 0.0)"),
    ("int", "float"): T("float({0})", "((double)({0}))"), ("int", "bool"): T("({0} != 0)"),
    ("bool", "float"): T("(1.0 if {0} else 0.0)", "(({0}) ? 1.0 : 0.0)"),
    ("bool", "int"): T("(1 if {0} else 0)", "(({0}) ? 1LL : 0LL)"),
}
_ROUND_EVEN = T("((float(round({0})) or {0} * 0.0) if -4.5e15 < {0} < 4.5e15 else {0})", "nearbyint({0})")
_ROUND_AWAY = T("_round_away({0})", "round({0})")
_INDEX = T("{0}[{1}]")


def _select_n(n: int) -> Tpl:
    py = "(" + ", ".join("{%d}" % (i + 1) for i in range(n)) + ")[{0}]"
    c = "{%d}" % n
    for i in range(n - 2, -1, -1):
        c = "(({0}) == %d ? {%d} : %s)" % (i, i + 1, c)
    return T(py, c)


def _clampi(hi: int) -> Tpl:
    return T("_clampi({0}, 0, %d)" % hi, "odc_clampi({0}, 0, %d)" % hi)


_CALL_PRIMS = ("jit", "pjit", "closed_call", "core_call", "remat", "checkpoint", "custom_jvp_call",
               "custom_vjp_call", "custom_vjp_call_jaxpr", "custom_lin")


class Lowered:
    """The generated Python function: ``fn(*runtime_args) -> tuple of flat lists`` (one per jaxpr output).

    Each runtime argument is a flat sequence of the corresponding jaxpr input's elements
    (row-major).  ``source`` is the generated Python source; ``n_ops`` its number of statements.
    """

    def __init__(self, source: str, fn: Callable, n_ops: int, out_sizes: list[int]):
        self.source = source
        self.fn = fn
        self.n_ops = n_ops
        self.out_sizes = out_sizes

    def __call__(self, *args):
        return self.fn(*args)


class _Line(NamedTuple):
    target: str
    tpl: Tpl | None      # None: a table (tuple / C array) of ``operands``
    operands: tuple
    kind: str
    used: tuple


class _Emitter:
    def __init__(self, max_unroll: int):
        self.lines: list[_Line] = []
        self.cse: dict[str, Ref] = {}
        self.kinds: dict[str, str] = {}
        self.counter = 0
        self.max_unroll = max_unroll

    # -- atoms ------------------------------------------------------------------------------
    def emit(self, tpl: Tpl, operands: Sequence[Any], kind: str):
        """Value of ``tpl`` on the operands: folded if all are constants, else a (shared) new local."""
        if tpl is IDENTITY or tpl.py == "{0}":
            return operands[0]
        expr = tpl.py.format(*[_lit(a) for a in operands])
        if not any(isinstance(a, Ref) for a in operands):
            return _py(eval(expr, RUNTIME), kind)  # noqa: S307 - our own template on literals
        return self._local(expr, "v", tpl, operands, kind)

    def table(self, atoms, kind):
        """A local tuple (C: array) holding ``atoms``, for indexing with a data-dependent index."""
        return self._local("(" + ", ".join(_lit(a) for a in atoms) + ",)", "t", None, atoms, kind)

    def _local(self, key: str, prefix: str, tpl, operands, kind):
        """The local named by ``key`` (its Python text): the existing one, else a new line."""
        if key in self.cse:
            return self.cse[key]
        self.counter += 1
        ref = Ref(f"{prefix}{self.counter}")
        self.lines.append(_Line(ref.name, tpl, tuple(operands), kind,
                                tuple(a.name for a in operands if isinstance(a, Ref))))
        self.cse[key] = ref
        self.kinds[ref.name] = kind
        return ref

    # -- elementwise --------------------------------------------------------------------------
    def elementwise(self, tpl: Tpl, arrays: Sequence[np.ndarray], kind: str, simplify=None) -> np.ndarray:
        shape = np.broadcast_shapes(*[a.shape for a in arrays])
        bs = [np.broadcast_to(a, shape).reshape(-1) for a in arrays]
        out = _objarray(shape)
        flat = out.reshape(-1)
        for i in range(flat.size):
            ops = [b[i] for b in bs]
            r = simplify(ops) if simplify is not None else None
            if r is None and tpl is _FLOAT_DIV and not isinstance(ops[1], Ref) and ops[1] != 0.0:
                r = self.emit(_FLOAT_DIV_NONZERO, ops, kind)  # a non-zero constant divisor cannot raise
            flat[i] = r if r is not None else self.emit(tpl, ops, kind)
        return out

    # -- jaxpr --------------------------------------------------------------------------------
    def run(self, jaxpr, consts: Sequence[np.ndarray], args: Sequence[np.ndarray]) -> list[np.ndarray]:
        env: dict[Any, np.ndarray] = {}

        def read(v):
            if type(v).__name__ == "Literal":
                return _const_array(v.val, _kind(v.aval.dtype))
            return env[v]

        def write(v, val):
            if type(v).__name__ == "DropVar":
                return
            env[v] = val

        for v, c in zip(jaxpr.constvars, consts):
            write(v, c)
        for v, a in zip(jaxpr.invars, args):
            write(v, a)
        for eqn in jaxpr.eqns:
            ins = [read(v) for v in eqn.invars]
            outs = self.eqn(eqn, ins)
            for v, o in zip(eqn.outvars, outs):
                aval_shape = tuple(v.aval.shape)
                if o.shape != aval_shape:
                    raise Unsupported(f"internal shape mismatch in {eqn.primitive.name}: {o.shape} vs {aval_shape}")
                write(v, o)
        return [read(v) for v in jaxpr.outvars]

    def closed(self, closed_jaxpr, args):
        consts = [_const_array(c, _kind(np.asarray(c).dtype)) for c in closed_jaxpr.consts]
        return self.run(closed_jaxpr.jaxpr, consts, args)

    def eqn(self, eqn, ins: list[np.ndarray]) -> list[np.ndarray]:
        name = eqn.primitive.name
        p = eqn.params
        out_avals = [v.aval for v in eqn.outvars]
        in_avals = [v.aval for v in eqn.invars]

        # -- calls: inline ---------------------------------------------------------------------
        if name in _CALL_PRIMS:
            sub = p.get("jaxpr") or p.get("call_jaxpr") or p.get("fun_jaxpr")
            if sub is None:
                raise Unsupported(f"call primitive {name} without a jaxpr")
            if hasattr(sub, "consts"):
                return self.closed(sub, ins)
            return self.run(sub, [], ins)

        kind = _kind(out_avals[0].dtype) if out_avals else "float"

        # -- elementwise -----------------------------------------------------------------------
        if name in _COMPARE:
            return [self.elementwise(_COMPARE[name], ins, "bool")]
        if name == "select_n":
            pred, cases = ins[0], ins[1:]
            pkind = _kind(in_avals[0].dtype)
            if len(cases) == 2 and pkind == "bool":
                def simp(ops):
                    c, a, b = ops
                    if not isinstance(c, Ref):
                        return b if c else a
                    if a is b or (not isinstance(a, Ref) and not isinstance(b, Ref) and _lit(a) == _lit(b)):
                        return a
                    return None
                return [self.elementwise(_SELECT2, [pred, *cases], kind, simp)]

            def simp_n(ops):
                if not isinstance(ops[0], Ref):
                    return ops[1 + int(ops[0])]
                return None
            return [self.elementwise(_select_n(len(cases)), [pred, *cases], kind, simp_n)]
        if name == "convert_element_type":
            src = _kind(in_avals[0].dtype)
            dst = _kind(p["new_dtype"])
            return [self.elementwise(_CONVERT[(src, dst)], ins, dst)]
        if name == "integer_pow":
            return [self.elementwise(_integer_pow_template(int(p["y"]), kind), ins, kind)]
        if name == "round":
            method = int(getattr(p["rounding_method"], "value", p["rounding_method"]))
            return [self.elementwise(_ROUND_EVEN if method == 1 else _ROUND_AWAY, ins, kind)]
        if name == "clamp":
            lo, x, hi = ins
            mx, mn = (_FLOAT_MAX, _FLOAT_MIN) if kind == "float" else (_INT_MAX, _INT_MIN)
            return [self.elementwise(mn, [self.elementwise(mx, [x, lo], kind), hi], kind)]
        in_kind = _kind(in_avals[0].dtype) if in_avals else kind
        unary = {"float": _FLOAT_UNARY, "int": _INT_UNARY, "bool": _BOOL_UNARY}[in_kind]
        binary = {"float": _FLOAT_BINARY, "int": _INT_BINARY, "bool": _BOOL_BINARY}[in_kind]
        if len(ins) == 1 and name in unary:
            return [self.elementwise(unary[name], ins, kind)]
        if len(ins) == 2 and name in binary:
            return [self.elementwise(binary[name], ins, kind, _simplifier(name, kind))]

        # -- structure (no code) ---------------------------------------------------------------
        if name == "reshape":
            if p.get("dimensions") not in (None, ()):
                raise Unsupported("reshape with dimensions")
            return [ins[0].reshape(tuple(p["new_sizes"]))]
        if name == "squeeze":
            return [np.squeeze(ins[0], axis=tuple(p["dimensions"])) if p["dimensions"] else ins[0]]
        if name == "expand_dims":
            return [np.expand_dims(ins[0], tuple(p["dimensions"]))]
        if name == "broadcast_in_dim":
            shape = tuple(p["shape"])
            dims = tuple(p["broadcast_dimensions"])
            op = ins[0]
            expanded_shape = [1] * len(shape)
            for d, s in zip(dims, op.shape):
                expanded_shape[d] = s
            return [np.array(np.broadcast_to(op.reshape(expanded_shape), shape), dtype=object)]
        if name == "slice":
            strides = p.get("strides") or (1,) * len(p["start_indices"])
            idx = tuple(slice(s, l, st) for s, l, st in zip(p["start_indices"], p["limit_indices"], strides))
            return [np.array(ins[0][idx], dtype=object)]
        if name == "concatenate":
            return [np.concatenate(ins, axis=p["dimension"])]
        if name == "split":
            cuts = np.cumsum(p["sizes"])[:-1]
            return [np.array(a, dtype=object) for a in np.split(ins[0], cuts, axis=p["axis"])]
        if name == "stack":
            return [np.stack(ins, axis=p.get("axis", 0))]
        if name == "transpose":
            return [np.array(np.transpose(ins[0], p["permutation"]), dtype=object)]
        if name == "rev":
            return [np.array(np.flip(ins[0], axis=tuple(p["dimensions"])), dtype=object)]
        if name == "pad":
            return [self.pad(ins[0], ins[1].reshape(-1)[0], p["padding_config"])]
        if name == "iota":
            shape = tuple(p["shape"])
            dim = p["dimension"]
            vals = np.broadcast_to(np.arange(shape[dim]).reshape([-1 if i == dim else 1 for i in range(len(shape))]), shape)
            return [_const_array(vals, _kind(p["dtype"]))]
        if name in ("reduce_sum", "reduce_max", "reduce_min", "reduce_prod", "reduce_and", "reduce_or"):
            return [self.reduce(name, ins[0], tuple(p["axes"]), kind)]
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], p["dimension_numbers"], kind)]
        if name in ("scatter", "scatter-add", "scatter_add", "scatter-mul", "scatter_mul", "scatter-min",
                    "scatter_min", "scatter-max", "scatter_max"):
            if p.get("update_consts"):
                raise Unsupported(f"{name} with update_consts")
            return [self.scatter(name.replace("_", "-"), ins[0], ins[1], ins[2], p["dimension_numbers"], p["mode"], kind)]
        if name == "gather":
            return [self.gather(ins[0], ins[1], p, tuple(out_avals[0].shape), kind)]
        if name == "dynamic_slice":
            return [self.dynamic_slice(ins[0], ins[1:], tuple(p["slice_sizes"]))]
        if name == "dynamic_update_slice":
            return [self.dynamic_update_slice(ins[0], ins[1], ins[2:])]

        # -- control flow ----------------------------------------------------------------------
        if name == "scan":
            return self.scan(p, ins)
        if name == "cond":
            return self.cond(p, ins)
        raise Unsupported(f"primitive {name!r}")

    # -- helpers for structured primitives ------------------------------------------------------
    def _chain(self, atoms, tpl, kind):
        acc = atoms[0]
        for a in atoms[1:]:
            acc = self.emit(tpl, [acc, a], kind)
        return acc

    @staticmethod
    def _const_indices(indices, what):
        flat = indices.reshape(-1)
        if any(isinstance(a, Ref) for a in flat):
            raise Unsupported(f"{what} with data-dependent indices")
        return np.array([int(a) for a in flat], dtype=np.int64).reshape(indices.shape)

    def scatter(self, name, operand, indices, updates, dnums, mode, kind):
        """XLA scatter with indices known at lowering time (index vector along the last axis of indices)."""
        if tuple(getattr(dnums, "operand_batching_dims", ()) or ()):
            raise Unsupported(f"{name} with batching dims")
        idx = self._const_indices(indices, name)
        uwd = tuple(dnums.update_window_dims)
        iwd = tuple(dnums.inserted_window_dims)
        sd2od = tuple(dnums.scatter_dims_to_operand_dims)
        scatter_dims = [d for d in range(updates.ndim) if d not in uwd]
        window_operand_dims = [d for d in range(operand.ndim) if d not in iwd]
        window_size = [1] * operand.ndim
        for ud, od in zip(uwd, window_operand_dims):
            window_size[od] = updates.shape[ud]
        clip = "CLIP" in str(mode)
        combine = {"scatter": None, "scatter-add": T("({0} + {1})"), "scatter-mul": T("({0} * {1})"),
                   "scatter-min": _FLOAT_MIN if kind == "float" else _INT_MIN,
                   "scatter-max": _FLOAT_MAX if kind == "float" else _INT_MAX}[name]
        out = np.array(operand, dtype=object)
        if idx.ndim == 0:
            idx = idx.reshape(1)
        for u in np.ndindex(*updates.shape):
            vec = idx[tuple(u[d] for d in scatter_dims)] if idx.ndim > 1 else idx
            start = [0] * operand.ndim
            for k, d in enumerate(sd2od):
                start[d] = int(vec[k])
            if clip:
                start = [min(max(s_, 0), n - w) for s_, n, w in zip(start, operand.shape, window_size)]
            elif any(s_ < 0 or s_ + w > n for s_, n, w in zip(start, operand.shape, window_size)):
                continue  # FILL_OR_DROP: out-of-bounds windows are dropped
            full = list(start)
            for ud, od in zip(uwd, window_operand_dims):
                full[od] += u[ud]
            full = tuple(full)
            out[full] = updates[u] if combine is None else self.emit(combine, [out[full], updates[u]], kind)
        return out

    def gather(self, operand, indices, p, out_shape, kind):
        """XLA gather with indices known at lowering time."""
        dn = p["dimension_numbers"]
        if tuple(getattr(dn, "operand_batching_dims", ()) or ()):
            raise Unsupported("gather with batching dims")
        idx = self._const_indices(indices, "gather")
        offset_dims = tuple(dn.offset_dims)
        collapsed = tuple(dn.collapsed_slice_dims)
        start_map = tuple(dn.start_index_map)
        slice_sizes = tuple(p["slice_sizes"])
        mode = str(p.get("mode"))
        fill = p.get("fill_value")
        batch_dims = [d for d in range(len(out_shape)) if d not in offset_dims]
        window_operand_dims = [d for d in range(operand.ndim) if d not in collapsed]
        out = _objarray(out_shape)
        for o in np.ndindex(*out_shape):
            vec = idx[tuple(o[d] for d in batch_dims)] if idx.ndim > 1 else idx
            start = [0] * operand.ndim
            for k, d in enumerate(start_map):
                start[d] = int(vec[k])
            oob = any(s_ < 0 or s_ + w > n for s_, n, w in zip(start, operand.shape, slice_sizes))
            if oob and "FILL" in mode:
                out[o] = _py(_nan if fill is None and kind == "float" else (fill if fill is not None else 0), kind)
                continue
            start = [min(max(s_, 0), n - w) for s_, n, w in zip(start, operand.shape, slice_sizes)]
            full = list(start)
            for od_out, od in zip(offset_dims, window_operand_dims):
                full[od] += o[od_out]
            out[o] = operand[tuple(full)]
        return out

    @staticmethod
    def pad(operand, value, config):
        out_shape = tuple(lo + hi + n + max(n - 1, 0) * interior for (lo, hi, interior), n in zip(config, operand.shape))
        if any(s < 0 for s in out_shape):
            raise Unsupported("pad to a negative size")
        out = _objarray(out_shape)
        out.reshape(-1)[:] = [value] * out.size
        for idx in np.ndindex(*operand.shape):
            pos = tuple(lo + i * (interior + 1) for i, (lo, _, interior) in zip(idx, config))
            if all(0 <= q < s for q, s in zip(pos, out_shape)):
                out[pos] = operand[idx]
        return out

    def reduce(self, name, arr, axes, kind):
        keep = [d for d in range(arr.ndim) if d not in axes]
        moved = np.transpose(arr, keep + list(axes))
        out_shape = tuple(arr.shape[d] for d in keep)
        groups = moved.reshape(out_shape + (-1,))
        tpl, empty = {
            "reduce_sum": (T("({0} + {1})"), 0), "reduce_prod": (T("({0} * {1})"), 1),
            "reduce_max": (_FLOAT_MAX if kind == "float" else _INT_MAX, None),
            "reduce_min": (_FLOAT_MIN if kind == "float" else _INT_MIN, None),
            "reduce_and": (_BOOL_AND, True), "reduce_or": (_BOOL_OR, False),
        }[name]
        out = _objarray(out_shape)
        flat_out = out.reshape(-1)
        flat_groups = groups.reshape(-1, groups.shape[-1])
        for i in range(flat_out.size):
            atoms = list(flat_groups[i])
            if not atoms:
                if empty is None:
                    raise Unsupported(f"{name} over an empty axis")
                flat_out[i] = _py(empty, kind)
            else:
                flat_out[i] = self._chain(atoms, tpl, kind)
        return out

    def dot_general(self, lhs, rhs, dimension_numbers, kind):
        (lc, rc), (lb, rb) = dimension_numbers
        lc, rc, lb, rb = map(tuple, (lc, rc, lb, rb))
        lfree = [d for d in range(lhs.ndim) if d not in lc and d not in lb]
        rfree = [d for d in range(rhs.ndim) if d not in rc and d not in rb]
        batch_shape = tuple(lhs.shape[d] for d in lb)
        out_shape = batch_shape + tuple(lhs.shape[d] for d in lfree) + tuple(rhs.shape[d] for d in rfree)
        contract_shape = tuple(lhs.shape[d] for d in lc)
        out = _objarray(out_shape)
        mul, add = T("({0} * {1})"), T("({0} + {1})")
        for idx in np.ndindex(*out_shape) if out_shape else [()]:
            b = idx[: len(lb)]
            li = idx[len(lb): len(lb) + len(lfree)]
            ri = idx[len(lb) + len(lfree):]
            terms = []
            for c in np.ndindex(*contract_shape) if contract_shape else [()]:
                lidx = [0] * lhs.ndim
                ridx = [0] * rhs.ndim
                for dims, vals, target in ((lb, b, lidx), (rb, b, ridx), (lfree, li, lidx), (rfree, ri, ridx),
                                           (lc, c, lidx), (rc, c, ridx)):
                    for d, v in zip(dims, vals):
                        target[d] = v
                terms.append(self.emit(mul, [lhs[tuple(lidx)], rhs[tuple(ridx)]], kind))
            out[idx] = self._chain(terms, add, kind) if terms else _py(0, kind)
        return out

    def _starts(self, operand_shape, starts, sizes):
        """Clamped start indices: Python ints when constant, else Refs to clamped locals."""
        result = []
        for dim, (s_arr, size) in enumerate(zip(starts, sizes)):
            s = s_arr.reshape(-1)[0]
            hi = operand_shape[dim] - size
            if not isinstance(s, Ref):
                result.append(min(max(int(s), 0), hi))
            else:
                result.append(self.emit(_clampi(hi), [s], "int"))
        return result

    def dynamic_slice(self, operand, starts, sizes):
        st = self._starts(operand.shape, starts, sizes)
        if all(not isinstance(s, Ref) for s in st):
            idx = tuple(slice(s, s + n) for s, n in zip(st, sizes))
            return np.array(operand[idx], dtype=object)
        strides = [int(np.prod(operand.shape[d + 1:])) for d in range(operand.ndim)]
        flat = list(operand.reshape(-1))
        kind = _atom_kind(flat, self.kinds)
        table = self.table(flat, kind)
        base_terms = []
        base_const = 0
        for s, stride in zip(st, strides):
            if isinstance(s, Ref):
                base_terms.append(s if stride == 1 else self.emit(T("({0} * %d)" % stride), [s], "int"))
            else:
                base_const += s * stride
        base = base_terms[0]
        for t in base_terms[1:]:
            base = self.emit(T("({0} + {1})"), [base, t], "int")
        out = _objarray(tuple(sizes))
        for idx in np.ndindex(*sizes):
            off = base_const + sum(i * stride for i, stride in zip(idx, strides))
            pos = base if off == 0 else self.emit(T("({0} + %d)" % off), [base], "int")
            out[idx] = self.emit(_INDEX, [table, pos], kind)
        return out

    def dynamic_update_slice(self, operand, update, starts):
        st = self._starts(operand.shape, starts, update.shape)
        if all(not isinstance(s, Ref) for s in st):
            out = np.array(operand, dtype=object)
            idx = tuple(slice(s, s + n) for s, n in zip(st, update.shape))
            out[idx] = update
            return out
        if operand.ndim != 1:
            raise Unsupported("dynamic_update_slice with a dynamic index on a multi-dimensional operand")
        kind = _atom_kind(list(operand.reshape(-1)), self.kinds)
        start = st[0]
        n = update.shape[0]
        out = _objarray(operand.shape)
        upd = self.table(list(update), kind)
        for j in range(operand.shape[0]):
            # element j comes from update[j - start] when start <= j < start + n
            inside = self.emit(T("(0 <= %d - {0} < %d)" % (j, n), "((%d - {0} >= 0) && (%d - {0} < %d))" % (j, j, n)),
                               [start], "bool")
            picked = self.emit(T("{0}[_clampi(%d - {1}, 0, %d)]" % (j, n - 1), "{0}[odc_clampi(%d - {1}, 0, %d)]" % (j, n - 1)),
                               [upd, start], kind)
            out[j] = self.emit(T("({1} if {0} else {2})", "({0} ? {1} : {2})"), [inside, picked, operand[j]], kind)
        return out

    def scan(self, p, ins):
        length = int(p["length"])
        if length > self.max_unroll:
            raise Unsupported(f"scan of length {length} (unrolled only up to {self.max_unroll})")
        n_consts, n_carry = int(p["num_consts"]), int(p["num_carry"])
        consts, carry, xs = ins[:n_consts], ins[n_consts:n_consts + n_carry], ins[n_consts + n_carry:]
        body = p["jaxpr"]
        ys_steps = []
        order = range(length - 1, -1, -1) if p.get("reverse") else range(length)
        for t in order:
            x_t = [np.array(x[t], dtype=object) for x in xs]
            outs = self.closed(body, [*consts, *carry, *x_t])
            carry = outs[:n_carry]
            ys_steps.append((t, outs[n_carry:]))
        ys_steps.sort(key=lambda item: item[0])
        n_ys = len(body.jaxpr.outvars) - n_carry
        ys = []
        for k in range(n_ys):
            if length == 0:
                aval = body.jaxpr.outvars[n_carry + k].aval
                ys.append(_objarray((0,) + tuple(aval.shape)))
            else:
                ys.append(np.stack([step[1][k] for step in ys_steps]))
        return [*carry, *ys]

    def cond(self, p, ins):
        index, ops = ins[0], ins[1:]
        branches = p["branches"]
        idx = index.reshape(-1)[0]
        if not isinstance(idx, Ref):
            i = min(max(int(idx), 0), len(branches) - 1)
            return self.closed(branches[i], ops)
        # pure branches: evaluate all, select by the index
        results = [self.closed(b, ops) for b in branches]
        clamped = self.emit(_clampi(len(branches) - 1), [idx], "int")
        outs = []
        for k in range(len(results[0])):
            kind = _atom_kind(list(results[0][k].reshape(-1)), self.kinds)
            cases = [r[k] for r in results]
            sel = np.array(clamped, dtype=object).reshape(())
            outs.append(self.elementwise(_select_n(len(cases)), [sel, *cases], kind))
        return outs


def _atom_kind(atoms, kinds=None) -> str:
    for a in atoms:
        if isinstance(a, Ref):
            if kinds and a.name in kinds:
                return kinds[a.name]
            continue
        if isinstance(a, bool):
            return "bool"
        if isinstance(a, int):
            return "int"
        if isinstance(a, float):
            return "float"
    return "float"


def _integer_pow_template(y: int, kind: str) -> Tpl:
    if y == 0:
        return T("1.0") if kind == "float" else T("1")
    n = abs(y)
    # exponentiation by squaring written out, as XLA does
    base = "{0}"
    acc = None
    while n:
        if n & 1:
            acc = base if acc is None else f"({acc} * {base})"
        n >>= 1
        if n:
            base = f"({base} * {base})"
    if y < 0:
        if kind == "float":
            return T(f"_div(1.0, {acc})", f"(1.0 / {acc})")
        return T(f"_idiv(1, {acc})", f"odc_idiv(1, {acc})")
    return T(acc)


def _is_const(a, value) -> bool:
    return not isinstance(a, Ref) and not isinstance(a, bool) and a == value and (
        math.copysign(1.0, a) == math.copysign(1.0, value) if isinstance(a, float) else True)


def _simplifier(name: str, kind: str):
    """Exact algebraic identities (bitwise identical for every float64, NaN and signed zero included)."""
    if kind == "bool":
        if name == "and":
            def simp(ops):
                a, b = ops
                for x, y in ((a, b), (b, a)):
                    if not isinstance(x, Ref):
                        return y if x else False
                return a if a is b else None
            return simp
        if name == "or":
            def simp(ops):
                a, b = ops
                for x, y in ((a, b), (b, a)):
                    if not isinstance(x, Ref):
                        return True if x else y
                return a if a is b else None
            return simp
        return None
    if kind != "float":
        return None
    if name == "mul":
        def simp(ops):
            a, b = ops
            if _is_const(b, 1.0) and isinstance(a, Ref):
                return a
            if _is_const(a, 1.0) and isinstance(b, Ref):
                return b
            return None
        return simp
    if name == "div":
        return lambda ops: ops[0] if _is_const(ops[1], 1.0) and isinstance(ops[0], Ref) else None
    if name == "sub":
        return lambda ops: ops[0] if _is_const(ops[1], 0.0) and isinstance(ops[0], Ref) else None
    if name == "add":
        def simp(ops):
            a, b = ops
            if _is_const(b, -0.0) and isinstance(a, Ref):
                return a
            if _is_const(a, -0.0) and isinstance(b, Ref):
                return b
            return None
        return simp
    return None


class Program:
    """A lowered jaxpr: straight-line code, rendered to Python (``to_python``) or C (``to_c``)."""

    def __init__(self, lines: list[_Line], inputs: list[tuple[int, int, str] | None], outs: list[np.ndarray],
                 kinds: dict[str, str]):
        self.lines = lines       # after dead-code elimination, in order
        self.inputs = inputs     # per jaxpr input: (position, size, kind) when a runtime argument, else None
        self.outs = outs
        self.kinds = kinds

    @property
    def n_ops(self) -> int:
        return len(self.lines)

    def to_python(self, name: str = "lowered") -> Lowered:
        params, header = [], []
        for spec in self.inputs:
            if spec is None:
                continue
            i, size, _ = spec
            params.append(f"A{i}")
            if size:
                header.append(", ".join(f"a{i}_{k}" for k in range(size)) + ("," if size == 1 else "") + f" = A{i}")
        body = [f"    {h}" for h in header]
        for line in self.lines:
            if line.tpl is None:
                body.append(f"    {line.target} = (" + ", ".join(_lit(a) for a in line.operands)
                            + ("," if len(line.operands) == 1 else "") + ")")
            else:
                body.append(f"    {line.target} = " + line.tpl.py.format(*[_lit(a) for a in line.operands]))
        ret = ", ".join("[" + ", ".join(_lit(a) for a in o.reshape(-1)) + "]" for o in self.outs)
        source = (f"def {name}({', '.join(params)}):\n" + "\n".join(body)
                  + f"\n    return ({ret}{',' if len(self.outs) == 1 else ''})\n")
        namespace = dict(RUNTIME)
        exec(compile(source, f"<lowered {name}>", "exec"), namespace)  # noqa: S102 - generated from the jaxpr
        return Lowered(source, namespace[name], len(self.lines), [int(o.size) for o in self.outs])

    def to_c(self, name: str = "lowered") -> str:
        """C99 source of ``void name(const double *A<i>..., double *R<j>...)`` (runtime inputs, then outputs).

        Every runtime input and every output is a flat float64 array.  Compile without fast-math
        and with ``-ffp-contract=off`` to keep IEEE float64 semantics identical to the Python dialect.
        """
        ctype = {"float": "double", "int": "long long", "bool": "int"}
        args, header = [], []
        for spec in self.inputs:
            if spec is None:
                continue
            i, size, kind = spec
            if kind != "float":
                raise Unsupported("C dialect: runtime inputs must be float64")
            args.append(f"const double *restrict A{i}")
            header += [f"    const double a{i}_{k} = A{i}[{k}];" for k in range(size)]
        for j, _ in enumerate(self.outs):
            args.append(f"double *restrict R{j}")
        body = list(header)
        for line in self.lines:
            t = ctype[line.kind]
            if line.tpl is None:
                body.append(f"    const {t} {line.target}[{len(line.operands)}] = {{"
                            + ", ".join(_lit_c(a) for a in line.operands) + "};")
            else:
                body.append(f"    const {t} {line.target} = " + line.tpl.c.format(*[_lit_c(a) for a in line.operands]) + ";")
        for j, o in enumerate(self.outs):
            for k, a in enumerate(o.reshape(-1)):
                body.append(f"    R{j}[{k}] = (double)({_lit_c(a)});")
        return f"void {name}({', '.join(args)})\n{{\n" + "\n".join(body) + "\n}\n"


def _lit_c(atom) -> str:
    if isinstance(atom, Ref):
        return atom.name
    if isinstance(atom, bool):
        return "1" if atom else "0"
    if isinstance(atom, int):
        return f"{atom}LL" if atom >= 0 else f"({atom}LL)"
    if isinstance(atom, float):
        if atom != atom:
            return "NAN"
        if atom in (_inf, -_inf):
            return "INFINITY" if atom > 0 else "(-INFINITY)"
        text = atom.hex()  # exact
        return f"({text})" if text.startswith("-") else text
    raise Unsupported(f"constant of type {type(atom).__name__}")


C_PRELUDE = r"""/* Generated by odocompass fmu/jaxpr_lower.py from the jaxpr of jaxmodel.run_from: do not edit. */
#include <math.h>
static inline double odc_sign(double x) { return x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : x); }
static inline long long odc_isign(long long x) { return (x > 0) - (x < 0); }
static inline long long odc_f2i(double x) {
    if (x != x) return 0;
    if (x >= 2147483647.0) return 2147483647LL;
    if (x <= -2147483648.0) return -2147483648LL;
    return (long long)x;
}
static inline long long odc_idiv(long long a, long long b) { return b == 0 ? -1 : a / b; }
static inline long long odc_irem(long long a, long long b) { return b == 0 ? a : a % b; }
static inline long long odc_clampi(long long i, long long lo, long long hi) { return i < lo ? lo : (i > hi ? hi : i); }
static inline double odc_logistic(double x) {
    if (x >= 0.0) return 1.0 / (1.0 + exp(-x));
    double e = exp(x);
    return e / (1.0 + e);
}
"""


def lower_program(closed_jaxpr, args: Sequence[Any], *, max_unroll: int = 8) -> Program:
    """Lower ``closed_jaxpr`` to a :class:`Program`.

    ``args`` has one entry per jaxpr input: ``None`` for a runtime argument, or a concrete value
    (array-like) folded in as a constant.
    """
    jaxpr = closed_jaxpr.jaxpr
    if len(args) != len(jaxpr.invars):
        raise ValueError(f"{len(args)} arguments for a jaxpr with {len(jaxpr.invars)} inputs")
    em = _Emitter(max_unroll)
    in_arrays, inputs = [], []
    for i, (v, a) in enumerate(zip(jaxpr.invars, args)):
        kind = _kind(v.aval.dtype)
        shape = tuple(v.aval.shape)
        if a is None:
            size = int(np.prod(shape))
            names = [f"a{i}_{k}" for k in range(size)]
            for n in names:
                em.kinds[n] = kind
            inputs.append((i, size, kind))
            in_arrays.append(_objarray(shape, [Ref(n) for n in names]))
        else:
            value = np.asarray(a)
            if value.shape != shape:
                raise ValueError(f"constant argument {i} has shape {value.shape}, expected {shape}")
            inputs.append(None)
            in_arrays.append(_const_array(value, kind))
    outs = em.closed(closed_jaxpr, in_arrays)

    # dead-code elimination from the outputs backwards
    needed = {a.name for o in outs for a in o.reshape(-1) if isinstance(a, Ref)}
    kept = []
    for line in reversed(em.lines):
        if line.target in needed:
            kept.append(line)
            needed.update(line.used)
    kept.reverse()
    return Program(kept, inputs, outs, em.kinds)


def lower_jaxpr(closed_jaxpr, args: Sequence[Any], *, name: str = "lowered", max_unroll: int = 8) -> Lowered:
    """Lower ``closed_jaxpr`` to a Python function (see :func:`lower_program` for ``args``).

    The function takes the runtime arguments in order (flat sequences) and returns a tuple with
    one flat list per jaxpr output.
    """
    return lower_program(closed_jaxpr, args, max_unroll=max_unroll).to_python(name)
