"""A computation few samples need, skipped on the samples where no drive of a batch needs it.

Under ``vmap`` a ``lax.cond`` whose predicate differs per drive becomes a selection: both branches run for every
drive on every sample.  The vernier's band widths (jaxmodel/vernier.py), read only on the eighth sample after a
rounded burst removal, cost 40-60 % of the default filter's time that way (bench/bench_run.py, stop 87).
``where_needed`` is batched by its own rule (``jax.custom_batching.custom_vmap``): one ``lax.cond`` on whether any
drive of the batch needs the value, which then computes it for all of them and keeps it where needed.  On
XLA:CPU only: elsewhere it is the plain selection.

Its value is a decision's input and carries no derivative (``custom_vmap`` has no reverse-mode rule): the arguments
pass through ``lax.stop_gradient``.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax import lax
from jax.custom_batching import custom_vmap


def _kept_where(needed, value):
    """``value`` where ``needed`` (broadcast over value's trailing axes), zeros elsewhere."""
    mask = jnp.reshape(needed, jnp.shape(needed) + (1,) * (jnp.ndim(value) - jnp.ndim(needed)))
    return jnp.where(mask, value, jnp.zeros_like(value))


def _computed_if_any(needed, fn, args):
    """fn(*args) kept where ``needed``, when any element of ``needed`` is true; zeros, without computing it, if none."""
    if jax.default_backend() != "cpu":
        # An accelerator reads a cond's predicate back to the host on every step of the scan; its vector units
        # compute the value for every drive at little cost (not measured here: no accelerator at stop 87).
        return _kept_where(needed, fn(*args))
    out_shape = jax.eval_shape(fn, *args)
    return lax.cond(jnp.any(needed), lambda: _kept_where(needed, fn(*args)),
                    lambda: jnp.zeros(out_shape.shape, out_shape.dtype))


def where_needed(needed, fn: Callable, *args):
    """fn(*args) where ``needed``, zeros elsewhere; not computed on a sample where no drive of the batch needs it.

    needed: bool (...,), the leading axes of fn's output; fn: arrays -> one array (..., *trailing), the same for
    every drive (no batch axis of its own); args: its arguments (their values are not differentiated).
    """
    args = tuple(lax.stop_gradient(jnp.asarray(a)) for a in args)

    @custom_vmap
    def needed_only(flags, *values):
        return _computed_if_any(flags, fn, values)

    @needed_only.def_vmap
    def _batched(axis_size, in_batched, flags, *values):
        flags, *values = [v if batched else jnp.broadcast_to(v, (axis_size,) + jnp.shape(v))
                          for v, batched in zip((flags, *values), in_batched)]
        return _computed_if_any(flags, jax.vmap(fn), values), True

    return needed_only(jnp.asarray(needed, bool), *args)
