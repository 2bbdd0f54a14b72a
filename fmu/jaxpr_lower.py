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
from typing import Any, Callable, Sequence

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
        return float(math.floor(x))
    except (ValueError, OverflowError):
        return x


def _ceil(x):
    try:
        return float(math.ceil(x))
    except (ValueError, OverflowError):
        return x


def _round_even(x):
    try:
        return float(round(x))
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


# Elementwise templates: (python template, kinds it accepts).  {0}, {1}, ... are operand literals.
_FLOAT_UNARY = {
    "neg": "(-{0})", "abs": "abs({0})", "sign": "_sign({0})",
    # |x| >= 2**52 is already integral; NaN and +-inf fail the comparison and pass through
    "floor": "(float(_mfloor({0})) if -4.5e15 < {0} < 4.5e15 else {0})",
    "ceil": "(float(_mceil({0})) if -4.5e15 < {0} < 4.5e15 else {0})",
    "is_finite": "({0} - {0} == 0.0)", "exp": "_exp({0})", "exp2": "_exp2({0})", "expm1": "_expm1({0})",
    "log": "_log({0})", "log1p": "_log1p({0})", "sin": "_sin({0})", "cos": "_cos({0})", "tan": "_tan({0})",
    "asin": "_asin({0})", "acos": "_acos({0})", "atan": "math.atan({0})", "sinh": "_sinh({0})",
    "cosh": "_cosh({0})", "tanh": "math.tanh({0})", "logistic": "_logistic({0})",
    "sqrt": "(_msqrt({0}) if {0} >= 0.0 else _nan)", "square": "({0} * {0})",
    "rsqrt": "(_div(1.0, _msqrt({0})) if {0} >= 0.0 else _nan)", "erf": "math.erf({0})",
    "lgamma": "math.lgamma({0})", "copy": "{0}", "copy_p": "{0}", "optimization_barrier": "{0}",
    "real": "{0}",
}
_FLOAT_DIV = "({0} / {1} if {1} else _div({0}, {1}))"
_FLOAT_BINARY = {
    "add": "({0} + {1})", "sub": "({0} - {1})", "mul": "({0} * {1})",
    "div": _FLOAT_DIV, "rem": "_rem({0}, {1})", "pow": "_pow({0}, {1})",
    "max": "({0} if ({0} >= {1} or {0} != {0}) else {1})", "min": "({0} if ({0} <= {1} or {0} != {0}) else {1})",
    "atan2": "math.atan2({0}, {1})", "nextafter": "math.nextafter({0}, {1})",
}
_INT_UNARY = {"neg": "(-{0})", "abs": "abs({0})", "sign": "_isign({0})", "not": "(~{0})", "copy": "{0}",
              "copy_p": "{0}", "optimization_barrier": "{0}"}
_INT_BINARY = {
    "add": "({0} + {1})", "sub": "({0} - {1})", "mul": "({0} * {1})", "div": "_idiv({0}, {1})",
    "rem": "_irem({0}, {1})", "max": "({0} if {0} >= {1} else {1})", "min": "({0} if {0} <= {1} else {1})",
    "and": "({0} & {1})", "or": "({0} | {1})", "xor": "({0} ^ {1})",
}
_BOOL_UNARY = {"not": "(not {0})", "copy": "{0}", "copy_p": "{0}", "optimization_barrier": "{0}"}
_BOOL_BINARY = {"and": "({0} and {1})", "or": "({0} or {1})", "xor": "({0} != {1})",
                "eq": "({0} == {1})", "ne": "({0} != {1})"}
_COMPARE = {"eq": "({0} == {1})", "ne": "({0} != {1})", "lt": "({0} < {1})", "le": "({0} <= {1})",
            "gt": "({0} > {1})", "ge": "({0} >= {1})"}

_CALL_PRIMS = ("jit", "pjit", "closed_call", "core_call", "remat", "checkpoint", "custom_jvp_call",
               "custom_vjp_call", "custom_vjp_call_jaxpr", "custom_lin")


class Lowered:
    """The generated function: ``fn(*runtime_args) -> tuple of flat lists`` (one per jaxpr output).

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


class _Emitter:
    def __init__(self, max_unroll: int):
        self.lines: list[tuple[str, str, tuple[str, ...]]] = []  # (target, expr, used names)
        self.cse: dict[str, Ref] = {}
        self.counter = 0
        self.max_unroll = max_unroll

    # -- atoms ------------------------------------------------------------------------------
    def emit(self, template: str, operands: Sequence[Any], kind: str):
        """Value of ``template`` on the operands: folded if all are constants, else a new local."""
        if template == "{0}":
            return operands[0]
        texts = [_lit(a) for a in operands]
        expr = template.format(*texts)
        if not any(isinstance(a, Ref) for a in operands):
            return _py(eval(expr, RUNTIME), kind)  # noqa: S307 - our own template on literals
        if expr in self.cse:
            return self.cse[expr]
        self.counter += 1
        ref = Ref(f"v{self.counter}")
        used = tuple(a.name for a in operands if isinstance(a, Ref))
        self.lines.append((ref.name, expr, used))
        self.cse[expr] = ref
        return ref

    # -- elementwise --------------------------------------------------------------------------
    def elementwise(self, template: str, arrays: Sequence[np.ndarray], kind: str, simplify=None) -> np.ndarray:
        shape = np.broadcast_shapes(*[a.shape for a in arrays])
        bs = [np.broadcast_to(a, shape).reshape(-1) for a in arrays]
        out = _objarray(shape)
        flat = out.reshape(-1)
        for i in range(flat.size):
            ops = [b[i] for b in bs]
            r = simplify(ops) if simplify is not None else None
            if r is None and template is _FLOAT_DIV and not isinstance(ops[1], Ref) and ops[1] != 0.0:
                r = self.emit("({0} / {1})", ops, kind)  # a non-zero constant divisor cannot raise
            flat[i] = r if r is not None else self.emit(template, ops, kind)
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
                return [self.elementwise("({2} if {0} else {1})", [pred, *cases], kind, simp)]
            tmpl = "(" + ", ".join("{%d}" % (i + 1) for i in range(len(cases))) + ")[{0}]"

            def simp_n(ops):
                if not isinstance(ops[0], Ref):
                    return ops[1 + int(ops[0])]
                return None
            return [self.elementwise(tmpl, [pred, *cases], kind, simp_n)]
        if name == "convert_element_type":
            src = _kind(in_avals[0].dtype)
            dst = _kind(p["new_dtype"])
            tmpl = {
                ("float", "float"): "{0}", ("int", "int"): "{0}", ("bool", "bool"): "{0}",
                ("float", "int"): "_f2i({0})", ("float", "bool"): "({0} != 0.0)",
                ("int", "float"): "float({0})", ("int", "bool"): "({0} != 0)",
                ("bool", "float"): "(1.0 if {0} else 0.0)", ("bool", "int"): "(1 if {0} else 0)",
            }[(src, dst)]
            return [self.elementwise(tmpl, ins, dst)]
        if name == "integer_pow":
            return [self.elementwise(_integer_pow_template(int(p["y"]), kind), ins, kind)]
        if name == "round":
            method = int(getattr(p["rounding_method"], "value", p["rounding_method"]))
            tmpl = "(float(round({0})) if -4.5e15 < {0} < 4.5e15 else {0})" if method == 1 else "_round_away({0})"
            return [self.elementwise(tmpl, ins, kind)]
        if name == "clamp":
            lo, x, hi = ins
            if kind == "float":
                inner = "({1} if ({1} >= {0} or {1} != {1}) else {0})"
                return [self.elementwise("_fmin(" + inner + ", {2})", [lo, x, hi], kind)]
            return [self.elementwise("min(max({1}, {0}), {2})", [lo, x, hi], kind)]
        in_kind = _kind(in_avals[0].dtype) if in_avals else kind
        if len(ins) == 1 and name in {"float": _FLOAT_UNARY, "int": _INT_UNARY, "bool": _BOOL_UNARY}[in_kind]:
            table = {"float": _FLOAT_UNARY, "int": _INT_UNARY, "bool": _BOOL_UNARY}[in_kind]
            return [self.elementwise(table[name], ins, kind)]
        if len(ins) == 2 and name in {"float": _FLOAT_BINARY, "int": _INT_BINARY, "bool": _BOOL_BINARY}[in_kind]:
            table = {"float": _FLOAT_BINARY, "int": _INT_BINARY, "bool": _BOOL_BINARY}[in_kind]
            return [self.elementwise(table[name], ins, kind, _simplifier(name, kind))]

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
        if name == "iota":
            shape = tuple(p["shape"])
            dim = p["dimension"]
            vals = np.broadcast_to(np.arange(shape[dim]).reshape([-1 if i == dim else 1 for i in range(len(shape))]), shape)
            return [_const_array(vals, _kind(p["dtype"]))]
        if name in ("reduce_sum", "reduce_max", "reduce_min", "reduce_prod", "reduce_and", "reduce_or"):
            return [self.reduce(name, ins[0], tuple(p["axes"]), kind)]
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], p["dimension_numbers"], kind)]
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
    def _chain(self, atoms, op_tmpl, kind):
        acc = atoms[0]
        for a in atoms[1:]:
            acc = self.emit(op_tmpl, [acc, a], kind)
        return acc

    def reduce(self, name, arr, axes, kind):
        keep = [d for d in range(arr.ndim) if d not in axes]
        moved = np.transpose(arr, keep + list(axes))
        out_shape = tuple(arr.shape[d] for d in keep)
        groups = moved.reshape(out_shape + (-1,))
        tmpl = {
            "reduce_sum": ("({0} + {1})", 0), "reduce_prod": ("({0} * {1})", 1),
            "reduce_max": (_FLOAT_BINARY["max"] if kind == "float" else _INT_BINARY["max"], None),
            "reduce_min": (_FLOAT_BINARY["min"] if kind == "float" else _INT_BINARY["min"], None),
            "reduce_and": ("({0} and {1})", True), "reduce_or": ("({0} or {1})", False),
        }[name]
        out = _objarray(out_shape)
        flat_out = out.reshape(-1)
        flat_groups = groups.reshape(-1, groups.shape[-1])
        for i in range(flat_out.size):
            atoms = list(flat_groups[i])
            if not atoms:
                if tmpl[1] is None:
                    raise Unsupported(f"{name} over an empty axis")
                flat_out[i] = _py(tmpl[1], kind)
            else:
                flat_out[i] = self._chain(atoms, tmpl[0], kind)
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
        for idx in np.ndindex(*out_shape) if out_shape else [()]:
            b = idx[: len(lb)]
            li = idx[len(lb): len(lb) + len(lfree)]
            ri = idx[len(lb) + len(lfree):]
            terms = []
            for c in np.ndindex(*contract_shape) if contract_shape else [()]:
                lidx = [0] * lhs.ndim
                ridx = [0] * rhs.ndim
                for d, v in zip(lb, b):
                    lidx[d] = v
                for d, v in zip(rb, b):
                    ridx[d] = v
                for d, v in zip(lfree, li):
                    lidx[d] = v
                for d, v in zip(rfree, ri):
                    ridx[d] = v
                for d, v in zip(lc, c):
                    lidx[d] = v
                for d, v in zip(rc, c):
                    ridx[d] = v
                terms.append(self.emit("({0} * {1})", [lhs[tuple(lidx)], rhs[tuple(ridx)]], kind))
            out[idx] = self._chain(terms, "({0} + {1})", kind) if terms else _py(0, kind)
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
                result.append(self.emit("_clampi({0}, 0, %d)" % hi, [s], "int"))
        return result

    def dynamic_slice(self, operand, starts, sizes):
        st = self._starts(operand.shape, starts, sizes)
        if all(not isinstance(s, Ref) for s in st):
            idx = tuple(slice(s, s + n) for s, n in zip(st, sizes))
            return np.array(operand[idx], dtype=object)
        # flat index = sum(start_d * stride_d) + offset of the element within the window
        strides = [int(np.prod(operand.shape[d + 1:])) for d in range(operand.ndim)]
        flat = list(operand.reshape(-1))
        table = self._table(flat)
        base_terms = []
        base_const = 0
        for s, stride in zip(st, strides):
            if isinstance(s, Ref):
                base_terms.append(s if stride == 1 else self.emit("({0} * %d)" % stride, [s], "int"))
            else:
                base_const += s * stride
        base = base_terms[0]
        for t in base_terms[1:]:
            base = self.emit("({0} + {1})", [base, t], "int")
        out = _objarray(tuple(sizes))
        for idx in np.ndindex(*sizes):
            off = base_const + sum(i * stride for i, stride in zip(idx, strides))
            pos = base if off == 0 else self.emit("({0} + %d)" % off, [base], "int")
            out[idx] = self.emit("{0}[{1}]", [table, pos], _atom_kind(flat))
        return out

    def _table(self, atoms):
        """A tuple local holding ``atoms`` (for dynamic indexing)."""
        body = ", ".join(_lit(a) for a in atoms) + ("," if len(atoms) == 1 else "")
        expr = f"({body})"
        if expr in self.cse:
            return self.cse[expr]
        self.counter += 1
        ref = Ref(f"t{self.counter}")
        self.lines.append((ref.name, expr, tuple(a.name for a in atoms if isinstance(a, Ref))))
        self.cse[expr] = ref
        return ref

    def dynamic_update_slice(self, operand, update, starts):
        st = self._starts(operand.shape, starts, update.shape)
        if all(not isinstance(s, Ref) for s in st):
            out = np.array(operand, dtype=object)
            idx = tuple(slice(s, s + n) for s, n in zip(st, update.shape))
            out[idx] = update
            return out
        if operand.ndim != 1:
            raise Unsupported("dynamic_update_slice with a dynamic index on a multi-dimensional operand")
        kind = _atom_kind(list(operand.reshape(-1)))
        start = st[0]
        n = update.shape[0]
        out = _objarray(operand.shape)
        upd = self._table(list(update))
        for j in range(operand.shape[0]):
            # element j comes from update[j - start] when start <= j < start + n
            inside = self.emit("(0 <= %d - {0} < %d)" % (j, n), [start], "bool")
            picked = self.emit("{0}[_clampi(%d - {1}, 0, %d)]" % (j, n - 1), [upd, start], kind)
            out[j] = self.emit("({1} if {0} else {2})", [inside, picked, operand[j]], kind)
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
        outs = []
        for k in range(len(results[0])):
            kind = _atom_kind(list(results[0][k].reshape(-1)) or [0.0])
            cases = [r[k] for r in results]
            if len(cases) == 2:
                pred = self.emit("({0} != 0)", [idx], "bool")
                outs.append(self.elementwise("({2} if {0} else {1})", [np.array(pred, dtype=object).reshape(()), *cases], kind))
            else:
                clamped = self.emit("_clampi({0}, 0, %d)" % (len(cases) - 1), [idx], "int")
                tmpl = "(" + ", ".join("{%d}" % (i + 1) for i in range(len(cases))) + ")[{0}]"
                outs.append(self.elementwise(tmpl, [np.array(clamped, dtype=object).reshape(()), *cases], kind))
        return outs


def _atom_kind(atoms) -> str:
    for a in atoms:
        if isinstance(a, bool):
            return "bool"
        if isinstance(a, int):
            return "int"
        if isinstance(a, float):
            return "float"
    return "float"


def _integer_pow_template(y: int, kind: str) -> str:
    if y == 0:
        return "1.0" if kind == "float" else "1"
    n = abs(y)
    # exponentiation by squaring written out, as XLA does
    terms = []
    base = "{0}"
    acc = None
    while n:
        if n & 1:
            acc = base if acc is None else f"({acc} * {base})"
        n >>= 1
        if n:
            base = f"({base} * {base})"
    if y < 0:
        return f"_div(1.0, {acc})" if kind == "float" else f"_idiv(1, {acc})"
    return acc


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


def lower_jaxpr(closed_jaxpr, args: Sequence[Any], *, name: str = "lowered", max_unroll: int = 8) -> Lowered:
    """Lower ``closed_jaxpr`` to Python.

    ``args`` has one entry per jaxpr input: ``None`` for a runtime argument (passed to the
    generated function as a flat sequence), or a concrete value (array-like) folded in as a
    constant.  Returns a :class:`Lowered` whose function takes the runtime arguments in order
    and returns a tuple with one flat list per jaxpr output.
    """
    jaxpr = closed_jaxpr.jaxpr
    if len(args) != len(jaxpr.invars):
        raise ValueError(f"{len(args)} arguments for a jaxpr with {len(jaxpr.invars)} inputs")
    em = _Emitter(max_unroll)
    in_arrays, header, params = [], [], []
    for i, (v, a) in enumerate(zip(jaxpr.invars, args)):
        kind = _kind(v.aval.dtype)
        shape = tuple(v.aval.shape)
        if a is None:
            size = int(np.prod(shape))
            names = [f"a{i}_{k}" for k in range(size)]
            params.append(f"A{i}")
            if size:
                header.append(", ".join(names) + (",", "")[size > 1] + f" = A{i}")
            in_arrays.append(_objarray(shape, [Ref(n) for n in names]))
        else:
            value = np.asarray(a)
            if value.shape != shape:
                raise ValueError(f"constant argument {i} has shape {value.shape}, expected {shape}")
            in_arrays.append(_const_array(value, kind))
    outs = em.closed(closed_jaxpr, in_arrays)

    # dead-code elimination from the outputs backwards
    needed = {a.name for o in outs for a in o.reshape(-1) if isinstance(a, Ref)}
    kept = []
    for target, expr, used in reversed(em.lines):
        if target in needed:
            kept.append((target, expr))
            needed.update(used)
    kept.reverse()
    body = [f"    {h}" for h in header] + [f"    {t} = {e}" for t, e in kept]
    ret = ", ".join("[" + ", ".join(_lit(a) for a in o.reshape(-1)) + "]" for o in outs)
    source = f"def {name}({', '.join(params)}):\n" + "\n".join(body) + f"\n    return ({ret}{',' if len(outs) == 1 else ''})\n"
    namespace = dict(RUNTIME)
    exec(compile(source, f"<lowered {name}>", "exec"), namespace)  # noqa: S102 - generated from the jaxpr
    return Lowered(source, namespace[name], len(kept), [int(o.size) for o in outs])
