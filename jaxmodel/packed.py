"""Sub-states of many scalars carried as one float64 vector.

Inside ``lax.scan`` XLA:CPU updates every carry buffer with its own small kernels; a sub-state of
ten or thirty scalars costs far less per step as one vector (measured in bench/bench_run.py:
refinement 13 -> 0.4 us, calibration 17 -> ~5 us per step).  ``packed_state`` builds that vector
type from a NamedTuple of named fields, so the code still reads ``state.ratio``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax


def packed_state(fields_type, name: str, doc: str):
    """A NamedTuple type ``name`` holding one float64 vector (..., len(fields_type._fields)).

    Each field of ``fields_type`` reads as a property (also on stacked states: ``vector[..., i]``);
    ``state.fields()`` unpacks to a ``fields_type``; ``Type.pack(fields)`` packs one.
    """

    reserved = {"vector", "fields", "pack", "count", "index"}
    clash = reserved.intersection(fields_type._fields) | {f for f in fields_type._fields if f.startswith("_")}
    if clash:
        raise ValueError(f"packed_state {name}: field names {sorted(clash)} would shadow the state's own attributes")

    class Packed(NamedTuple):
        vector: jnp.ndarray

    def fields(self):
        return fields_type(*[self.vector[..., i] for i in range(len(fields_type._fields))])

    def pack(values):
        return Packed(jnp.stack([jnp.asarray(v, jnp.float64) for v in values], axis=-1))

    Packed.__name__ = Packed.__qualname__ = name
    Packed.__module__ = fields_type.__module__  # the module that declares the fields (pickling, repr)
    Packed.__doc__ = doc
    Packed.fields = fields
    Packed.pack = staticmethod(pack)
    for i, field in enumerate(fields_type._fields):
        setattr(Packed, field, property(lambda self, i=i: self.vector[..., i]))
    return Packed


def computed_once(flag):
    """``flag`` (bool, per drive), made a value XLA:CPU computes once.

    A flag from a chain of cheap operations (comparisons, selections, reads of the sample), broadcast over
    a packed state vector, is recomputed by XLA:CPU for every field of it: the filter's ``ok`` alone cost
    17 of 66 us per step (64 drives).  A square root, exact on 0 and 1, is an operation it does not repeat.
    """
    return jnp.sqrt(jnp.where(flag, 1.0, 0.0)) > 0.5


@jax.custom_jvp
def value_once(value):
    """``value`` (float, per drive), made a value XLA:CPU computes once, as ``computed_once`` does for a flag.

    A scalar from a long chain of cheap operations is recomputed by every kernel that reads it: the rate filter's
    one-field additions (``offset_filter.added``) recomputed theirs for each of its 37 fields, 32 of ~470 us per step
    (64 drives, stop 76).  A reduction is a kernel of its own where several kernels read it (XLA:CPU may fuse it into
    a single elementwise reader, which then computes it once per element it writes, as it should).  It reduces the
    value's bits as an integer, the maximum with the smallest int64, so that it returns ``value`` bit for bit: -0.0,
    inf, NaN and subnormals included (a float maximum flushes subnormals to zero where XLA:CPU runs with denormals
    off, as the test suite's flags and eager dispatch do).  Its tangent is the value's own (``_value_once_jvp``).
    """
    bits = lax.bitcast_convert_type(jnp.asarray(value, jnp.float64), jnp.int64)
    floor = jnp.full_like(bits, jnp.iinfo(jnp.int64).min)
    return lax.bitcast_convert_type(jnp.max(jnp.stack([bits, floor], axis=-1), axis=-1), jnp.float64)


@value_once.defjvp
def _value_once_jvp(primals, tangents):
    # The identity's tangent: the maximum's own would divide by the count of elements equal to it, 0 where the value is
    # NaN, and so make a NaN cotangent on a branch a double-where had masked.
    return value_once(primals[0]), jnp.asarray(tangents[0], jnp.float64)
