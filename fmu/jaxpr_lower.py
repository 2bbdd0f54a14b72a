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

The lowering is three files, each self-contained (they import neither jax nor the project)
so that the FMU can bundle them; they read jaxpr objects only through their public attributes:

* this module: the walk over the jaxpr (``_Emitter``) and the entry points :func:`lower_program`
  and :func:`lower_jaxpr`;
* ``lowered_code``: what it emits -- atoms, the per-primitive templates in Python and C, and the
  :class:`Program` with its rendering to either dialect;
* ``lowering_runtime``: what the emitted code calls -- :data:`RUNTIME` (Python) and
  :data:`C_PRELUDE` (C).

The public names of all three are importable from here.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .lowered_code import (
    _BITS2F, _BOOL_AND, _BOOL_BINARY, _BOOL_OR, _BOOL_UNARY, _COMPARE, _CONVERT, _F2BITS, _FLOAT_BINARY, _FLOAT_DIV,
    _FLOAT_DIV_NONZERO, _FLOAT_MAX, _FLOAT_MIN, _FLOAT_UNARY, _INDEX, _INT64_MIN, _INT_BINARY, _INT_MAX, _INT_MIN,
    _INT_UNARY, _ROUND_AWAY, _ROUND_EVEN, _SELECT2, IDENTITY, Lowered, Program, Ref, T, Tpl, Unsupported,
    _atom_kind, _clampi, _const_array, _integer_pow_template, _kind, _Line, _lit, _objarray, _py,
    _select_n, _simplifier,
)
from .lowering_runtime import C_PRELUDE, RUNTIME, _nan

__all__ = ["Unsupported", "Lowered", "Program", "lower_program", "lower_jaxpr", "RUNTIME", "C_PRELUDE"]


_CALL_PRIMS = ("jit", "pjit", "closed_call", "core_call", "remat", "checkpoint", "custom_jvp_call",
               "custom_vjp_call", "custom_vjp_call_jaxpr", "custom_lin", "custom_vmap_call")


class _Emitter:
    def __init__(self, max_unroll: int):
        self.lines: list[_Line] = []
        self.cse: dict[str, Ref] = {}
        self.kinds: dict[str, str] = {}
        self.counter = 0
        self.max_unroll = max_unroll
        self.bitcast_of: dict[str, tuple[Tpl, Any]] = {}  # a bitcast's local -> (its template, its operand)

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
        """The output arrays of one jaxpr equation, from its input arrays."""
        name = eqn.primitive.name
        if name in _CALL_PRIMS:
            return self._inline_call(eqn, ins)
        kind = _kind(eqn.outvars[0].aval.dtype) if eqn.outvars else "float"
        # elementwise first: besides its own primitives, it refuses an unsupported input dtype for all the others
        for lower_family in (self._elementwise_eqn, self._shape_eqn, self._array_eqn, self._control_eqn):
            outs = lower_family(eqn, ins, kind)
            if outs is not None:
                return outs
        raise Unsupported(f"primitive {name!r}")

    # -- one family of primitives each: the outputs, or None when ``eqn`` is not of the family ------
    def _inline_call(self, eqn, ins):
        """Call primitives (jit, pjit, custom_jvp_call, ...): the called jaxpr lowered in place."""
        name, p = eqn.primitive.name, eqn.params
        sub = p.get("jaxpr") or p.get("call_jaxpr") or p.get("fun_jaxpr") or p.get("call")
        if sub is None:
            raise Unsupported(f"call primitive {name} without a jaxpr")
        if hasattr(sub, "consts"):
            return self.closed(sub, ins)
        return self.run(sub, [], ins)

    def _elementwise_eqn(self, eqn, ins, kind):
        """Elementwise primitives: comparisons, selections, conversions and the unary/binary arithmetic."""
        name, p = eqn.primitive.name, eqn.params
        in_avals = [v.aval for v in eqn.invars]
        if name == "stop_gradient":  # an identity on values (jaxmodel/seldom.py's arguments)
            return [ins[0]]
        if name in _COMPARE:
            return [self.elementwise(_COMPARE[name], ins, "bool")]
        if name == "select_n":
            return [self._select_eqn(ins, _kind(in_avals[0].dtype), kind)]
        if name == "convert_element_type":
            src = _kind(in_avals[0].dtype)
            dst = _kind(p["new_dtype"])
            return [self.elementwise(_CONVERT[(src, dst)], ins, dst)]
        if name == "bitcast_convert_type":
            return [self._bitcast_eqn(ins[0], in_avals[0].dtype, p["new_dtype"])]
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
        return None

    def _bitcast_eqn(self, arr, src_dtype, dst_dtype):
        """``bitcast_convert_type`` between float64 and int64, the bits unchanged; a round trip folds to its operand."""
        src, dst = np.dtype(src_dtype), np.dtype(dst_dtype)
        if src.itemsize != 8 or dst.itemsize != 8 or {_kind(src), _kind(dst)} != {"float", "int"}:
            raise Unsupported(f"bitcast_convert_type {src} -> {dst} (only float64 <-> int64)")
        tpl = _F2BITS if _kind(src) == "float" else _BITS2F

        def fold(ops):
            back = self.bitcast_of.get(ops[0].name) if isinstance(ops[0], Ref) else None
            return back[1] if back is not None and back[0] is not tpl else None

        out = self.elementwise(tpl, [arr], _kind(dst), fold)
        for x, y in zip(np.asarray(arr).reshape(-1), out.reshape(-1)):
            if isinstance(y, Ref) and y is not x:
                self.bitcast_of.setdefault(y.name, (tpl, x))
        return out

    def _select_eqn(self, ins, pred_kind, kind):
        """``select_n``: the case picked by the predicate, folded when the predicate or the cases allow."""
        pred, cases = ins[0], ins[1:]
        if len(cases) == 2 and pred_kind == "bool":
            def simp(ops):
                c, a, b = ops
                if not isinstance(c, Ref):
                    return b if c else a
                if a is b or (not isinstance(a, Ref) and not isinstance(b, Ref) and _lit(a) == _lit(b)):
                    return a
                return None
            return self.elementwise(_SELECT2, [pred, *cases], kind, simp)

        def simp_n(ops):
            if not isinstance(ops[0], Ref):
                return ops[1 + int(ops[0])]
            return None
        return self.elementwise(_select_n(len(cases)), [pred, *cases], kind, simp_n)

    def _shape_eqn(self, eqn, ins, kind):
        """Shape primitives (reshape, broadcast, slice, concatenate, transpose, pad, iota, ...): no code emitted."""
        name, p = eqn.primitive.name, eqn.params
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
        return None

    def _array_eqn(self, eqn, ins, kind):
        """Whole-array primitives (reductions, dot_general, scatter, gather, dynamic slices), by the helpers below."""
        name, p = eqn.primitive.name, eqn.params
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
            return [self.gather(ins[0], ins[1], p, tuple(eqn.outvars[0].aval.shape), kind)]
        if name == "dynamic_slice":
            return [self.dynamic_slice(ins[0], ins[1:], tuple(p["slice_sizes"]))]
        if name == "dynamic_update_slice":
            return [self.dynamic_update_slice(ins[0], ins[1], ins[2:])]
        return None

    def _control_eqn(self, eqn, ins, kind):
        """Control flow: ``scan`` unrolled, ``cond`` folded or all branches selected by the index."""
        name, p = eqn.primitive.name, eqn.params
        if name == "scan":
            return self.scan(p, ins)
        if name == "cond":
            return self.cond(p, ins)
        return None

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
            if name == "reduce_max" and kind == "int" and any(isinstance(a, Ref) for a in atoms):
                atoms = [a for a in atoms if isinstance(a, Ref) or a != _INT64_MIN]  # the maximum's identity
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
