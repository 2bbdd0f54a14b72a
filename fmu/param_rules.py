"""Parameter validity rules read off ``jaxmodel.validate_params`` itself, for the native FMU's C
check and the model description's min/max (issue 12).

Nothing here lists parameters by hand.  For every numeric key of ``PARAMETER_TABLE`` the rules are
found by asking ``validate_params`` (one key changed at a time from the defaults; a value counts
as refused for that key when the message names the key):

* ``finite``: NaN is refused;
* an interval: the accepted values of a probe grid (the floats next to 0 and 1, and magnitudes from
  1e-324 to 1e300) bracket each bound, which bisection on the float64 order then finds exactly
  (open or closed);
* an order between two keys (``refine_speed_min <= refine_speed_max``): a refusal whose message
  names a second key.

``check(rules, values)`` applies the rules in Python; ``derive`` verifies it against
``validate_params`` on random parameter sets (several keys changed at once) and raises if they
disagree, so a new kind of rule in ``jaxmodel`` stops the native build instead of slipping through.
``to_c(rules, index)`` writes the C function ``odc_validate`` from the same rules.
"""

from __future__ import annotations

import math
import re
from typing import Any, Mapping, NamedTuple

import numpy as np

TINY = 5e-324
GRID = (-1e300, -1e15, -1e9, -1e3, -2.0, -1.0, -0.5, -TINY, 0.0, TINY, 0.25, 0.5, math.nextafter(1.0, 0.0), 1.0,
        math.nextafter(1.0, 2.0), 2.0, 3.0, 10.0, 30.0, 100.0, 1e3, 1e6, 1e9, 1e15, 1e300)


class Interval(NamedTuple):
    key: str
    lo: float | None
    lo_open: bool
    hi: float | None
    hi_open: bool

    def ok(self, v: float) -> bool:
        if self.lo is not None and not (v > self.lo if self.lo_open else v >= self.lo):
            return False
        if self.hi is not None and not (v < self.hi if self.hi_open else v <= self.hi):
            return False
        return True

    def text(self) -> str:
        lo = "-inf" if self.lo is None else repr(self.lo)
        hi = "inf" if self.hi is None else repr(self.hi)
        return f"{'(' if self.lo_open or self.lo is None else '['}{lo}, {hi}{')' if self.hi_open or self.hi is None else ']'}"

    def bounds(self) -> tuple[float | None, float | None]:
        """Inclusive (min, max) for the model description."""
        lo = None if self.lo is None else (math.nextafter(self.lo, math.inf) if self.lo_open else self.lo)
        hi = None if self.hi is None else (math.nextafter(self.hi, -math.inf) if self.hi_open else self.hi)
        return lo, hi


class Order(NamedTuple):
    lower: str  # lower <= upper
    upper: str


class Rules(NamedTuple):
    finite: tuple[str, ...]
    intervals: tuple[Interval, ...]
    orders: tuple[Order, ...]


def _named(message: str, key: str) -> bool:
    return re.search(rf"(?<![\w.]){re.escape(key)}(=| is )", message) is not None


class _Probe:
    def __init__(self, jm):
        from jaxmodel import params as P

        self.P = P
        self.jm = jm
        self.defaults = {s.key: np.asarray(jm.make_params()[i], dtype=np.float64)
                         for i, s in enumerate(P.PARAMETER_TABLE)}

    def message(self, changes: Mapping[str, float]) -> str:
        vals = dict(self.defaults)
        for k, v in changes.items():
            vals[k] = np.full_like(self.defaults[k], v)
        try:
            self.P.validate_params(self.P.Params(**vals))
        except self.P.ParameterError as exc:
            return str(exc)
        return ""


def _ordered(x: float) -> int:
    i = int(np.float64(x).view(np.int64))
    return i if i >= 0 else -(i & 0x7FFFFFFFFFFFFFFF)


def _from_ordered(i: int) -> float:
    bits = i if i >= 0 else (-i) | (1 << 63)
    return float(np.int64(np.uint64(bits).astype(np.int64)).view(np.float64))


_ROUND = sorted({sign * k * 10.0 ** e for sign in (-1.0, 1.0) for k in range(1, 100) for e in range(-20, 21)}
                | {0.0})


def _boundary(refused, rejected: float, accepted: float) -> tuple[float, bool]:
    """The bound between a refused and an accepted value: (bound, open).  Round numbers (two
    significant digits) between them are searched first, then bisection on the float64 order."""
    lo, hi = min(rejected, accepted), max(rejected, accepted)
    cands = [c for c in _ROUND if lo < c < hi]
    r, a = rejected, accepted
    while cands:  # binary search over the round numbers
        mid = cands[len(cands) // 2]
        if refused(mid):  # the bound lies on the accepted side of mid
            r = mid
        else:
            a = mid
        cands = [c for c in cands if (min(r, a) < c < max(r, a))]
    toward_a = math.inf if accepted > rejected else -math.inf
    if math.nextafter(r, toward_a) == a:
        pass
    elif not refused(math.nextafter(r, toward_a)):  # an open bound at the round number r
        return r, True
    elif refused(math.nextafter(a, -toward_a)):  # a closed bound at the round number a
        return a, False
    ri, ai = _ordered(r), _ordered(a)
    while abs(ai - ri) > 1:
        mid = (ai + ri) // 2
        if refused(_from_ordered(mid)):
            ri = mid
        else:
            ai = mid
    rv, av = _from_ordered(ri), _from_ordered(ai)
    for nice in (0.0, 1.0):  # (0, ...) rather than [5e-324, ...)
        if rv == nice:
            return nice, True
    return av, False


_CACHE: dict[str, Rules] = {}


def derive(jm=None, string_keys=("sensor_axle",), fuzz: int = 400, seed: int = 0) -> Rules:
    """The rules of this ``jaxmodel`` (cached per process by the text of jaxmodel/params.py)."""
    if jm is None:
        import jaxmodel as jm
    import hashlib
    from pathlib import Path

    from jaxmodel import params as P

    key = hashlib.sha256(Path(P.__file__).read_bytes() + repr((string_keys, fuzz, seed)).encode()).hexdigest()
    if key not in _CACHE:
        _CACHE[key] = _derive(jm, string_keys, fuzz, seed)
    return _CACHE[key]


def _derive(jm, string_keys, fuzz, seed) -> Rules:
    probe = _Probe(jm)
    keys = [s.key for s in jm.PARAMETER_TABLE if s.key not in string_keys]
    finite, intervals, orders = [], [], []
    for k in keys:
        if _named(probe.message({k: math.nan}), k):
            finite.append(k)
        verdict = {}
        for v in GRID:
            msg = probe.message({k: v})
            others = [j for j in keys if j != k and _named(msg, j)]
            if _named(msg, k) and others:
                for j in others:
                    lower = v > float(probe.defaults[j].reshape(-1)[0])
                    order = Order(k, j) if lower else Order(j, k)
                    if order not in orders:
                        orders.append(order)
                verdict[v] = None  # refused by an order, not by k's own interval
            else:
                verdict[v] = not _named(msg, k)
        acc = [v for v in GRID if verdict[v]]
        if not acc:
            raise RuntimeError(f"param_rules: no probe value of {k!r} is accepted by validate_params")
        lo, lo_open, hi, hi_open = None, False, None, False

        def refused(x, k=k):
            return _named(probe.message({k: x}), k)

        below = [v for v in GRID if v < acc[0] and verdict[v] is False]
        if below:
            lo, lo_open = _boundary(refused, below[-1], acc[0])
        above = [v for v in GRID if v > acc[-1] and verdict[v] is False]
        if above:
            b, b_open = _boundary(refused, above[0], acc[-1])
            hi, hi_open = b, b_open
        if lo is not None or hi is not None:
            intervals.append(Interval(k, lo, lo_open, hi, hi_open))
    rules = Rules(tuple(finite), tuple(intervals), tuple(orders))
    _verify(rules, probe, keys, fuzz, seed)
    return rules


def check(rules: Rules, values: Mapping[str, Any]) -> list[str]:
    """Keys refused by ``rules`` (values: key -> number or array)."""
    bad = []
    for k in rules.finite:
        if not np.all(np.isfinite(np.asarray(values[k], dtype=np.float64))):
            bad.append(k)
    for r in rules.intervals:
        if not r.ok(float(np.asarray(values[r.key]).reshape(-1)[0])) and r.key not in bad:
            bad.append(r.key)
    for o in rules.orders:
        if not float(values[o.lower]) <= float(values[o.upper]):
            bad += [k for k in (o.lower, o.upper) if k not in bad]
    return bad


def _verify(rules: Rules, probe: _Probe, keys, n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    pool = list(GRID) + [math.nan, 3.0, 10.0, 1e-3, -1e-3, 0.999, 1.001]
    for case in range(n):
        changes = {}
        for k in rng.choice(keys, size=int(rng.integers(1, 4)), replace=False):
            changes[str(k)] = float(rng.choice(pool)) if rng.random() < 0.7 else \
                float(probe.defaults[str(k)].reshape(-1)[0]) * float(rng.uniform(-2.0, 3.0))
        msg = probe.message(changes)
        vals = {k: (np.full_like(probe.defaults[k], changes[k]) if k in changes else probe.defaults[k]) for k in keys}
        mine = set(check(rules, vals))
        theirs = {k for k in keys if _named(msg, k)}
        if mine != theirs:
            raise RuntimeError(f"param_rules: the derived rules disagree with jaxmodel.validate_params for {changes}: "
                               f"refused {sorted(mine)} here, {sorted(theirs)} there ({msg!r}); "
                               "fmu/param_rules.py does not know this kind of rule")


def bounds(rules: Rules) -> dict[str, tuple[float | None, float | None]]:
    return {r.key: r.bounds() for r in rules.intervals}


def _c_num(x: float) -> str:
    return x.hex() if x >= 0 else f"({x.hex()})"


def to_c(rules: Rules, index: Mapping[str, tuple[int, int]]) -> str:
    """``int odc_validate(const double *p, char *msg, size_t n)``: the number of refused keys, their
    messages appended to ``msg``.  ``index``: key -> (flat offset, size) in the parameter vector."""
    lines = ["/* Generated by odocompass fmu/param_rules.py from jaxmodel.validate_params: do not edit. */",
             "#include <math.h>", "#include <stdio.h>", "#include <string.h>", "",
             "static void odc_append(char *msg, size_t n, const char *text) {",
             "    size_t used = strlen(msg);",
             "    if (used + 3 < n) snprintf(msg + used, n - used, \"%s%s\", used ? \"; \" : \"\", text);", "}", "",
             "int odc_validate(const double *p, char *msg, size_t n)", "{",
             "    char buf[256];", "    int bad = 0;", "    int i;", "    (void)i;"]
    refused_flag = {}
    for k in sorted(set(rules.finite) | {r.key for r in rules.intervals} | {x for o in rules.orders for x in o}):
        refused_flag[k] = f"f{len(refused_flag)}"
        lines.append(f"    int {refused_flag[k]} = 0; /* {k} */")
    for k in rules.finite:
        off, size = index[k]
        lines.append(f"    for (i = 0; i < {size}; i++) if (!isfinite(p[{off} + i])) {{ {refused_flag[k]} = 1; }}")
        lines.append(f"    if ({refused_flag[k]}) {{ odc_append(msg, n, \"{k} is not finite\"); bad++; }}")
    for r in rules.intervals:
        off, _ = index[r.key]
        conds = []
        if r.lo is not None:
            conds.append(f"p[{off}] {'>' if r.lo_open else '>='} {_c_num(r.lo)}")
        if r.hi is not None:
            conds.append(f"p[{off}] {'<' if r.hi_open else '<='} {_c_num(r.hi)}")
        f = refused_flag[r.key]
        lines.append(f"    if (!{f} && !({' && '.join(conds)})) {{")
        lines.append(f"        snprintf(buf, sizeof buf, \"{r.key}=%.17g outside {r.text()}\", p[{off}]);")
        lines.append(f"        odc_append(msg, n, buf); {f} = 1; bad++;")
        lines.append("    }")
    for o in rules.orders:
        lo, hi = index[o.lower][0], index[o.upper][0]
        lines.append(f"    if (!(p[{lo}] <= p[{hi}])) {{")
        lines.append(f"        snprintf(buf, sizeof buf, \"{o.lower}=%.17g above {o.upper}=%.17g\", p[{lo}], p[{hi}]);")
        lines.append("        odc_append(msg, n, buf); bad++;")
        lines.append("    }")
    lines += ["    return bad;", "}", ""]
    return "\n".join(lines)
