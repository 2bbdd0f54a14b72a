"""The code that ``fmu/jaxpr_lower.py`` emits: atoms, per-primitive templates, and the :class:`Program`.

* atoms: a value of the jaxpr is a numpy object array of atoms, each a Python constant or a
  :class:`Ref` to a local of the generated code; ``_lit`` / ``_lit_c`` write them as literals;
* templates: a :class:`Tpl` writes one elementwise operation in both dialects (Python, C), with
  tables per primitive and operand kind, and the exact algebraic identities that skip one;
* :class:`Program`: the straight-line lines left after dead-code elimination, rendered to a
  Python function (:class:`Lowered`, run in ``lowering_runtime.RUNTIME``) or to C source (linked
  with ``lowering_runtime.C_PRELUDE``).

Imports neither jax nor the project (only numpy and its sibling ``lowering_runtime``), so that
the FMU can bundle it.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np

from .lowering_runtime import RUNTIME, _inf


class Unsupported(Exception):
    """The jaxpr uses something this lowering does not translate (the caller falls back to XLA)."""


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


class Tpl(NamedTuple):
    """An operation in both dialects: Python source and C source, operands as {0}, {1}, ..."""

    py: str
    c: str


def T(py: str, c: str | None = None) -> Tpl:
    return Tpl(py, py if c is None else c)


IDENTITY = T("{0}")

# Elementwise templates by input kind.  Python: the helpers of lowering_runtime reproduce IEEE float64 where
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
_F2BITS = T("_f2bits({0})", "odc_f2bits({0})")
_BITS2F = T("_bits2f({0})", "odc_bits2f({0})")
_INT64_MIN = -(2**63)
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
        if atom == _INT64_MIN:  # its magnitude does not fit a long long literal
            return "(-9223372036854775807LL - 1)"
        return f"{atom}LL" if atom >= 0 else f"({atom}LL)"
    if isinstance(atom, float):
        if atom != atom:
            return "NAN"
        if atom in (_inf, -_inf):
            return "INFINITY" if atom > 0 else "(-INFINITY)"
        text = atom.hex()  # exact
        return f"({text})" if text.startswith("-") else text
    raise Unsupported(f"constant of type {type(atom).__name__}")
