"""jaxmodel/seldom.py: a value computed only on the samples where some drive needs it."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxmodel.seldom import where_needed


def _widths(x):
    return jnp.stack([jnp.sin(x), x * x])


def _scan(needed, xs, fn=_widths):
    """The sum over a drive of where_needed's value of ``fn``, as a scan step uses it."""
    def body(total, sample):
        flag, x = sample
        return total + where_needed(flag, fn, x), None
    return lax.scan(body, jnp.zeros(2), (needed, xs))[0]


def test_the_value_is_the_function_where_needed_and_zero_elsewhere_batched_or_not():
    rng = np.random.default_rng(0)
    xs = rng.normal(size=(5, 40))
    needed = rng.random((5, 40)) < 0.2
    needed[2] = False  # a drive that never needs it, in a batch where others do
    expected = np.where(needed[..., None], np.stack([np.sin(xs), xs * xs], axis=-1), 0.0).sum(axis=1)
    np.testing.assert_allclose(jax.jit(jax.vmap(_scan))(needed, xs), expected, rtol=1e-12)
    np.testing.assert_allclose(_scan(needed[0], xs[0]), expected[0], rtol=1e-12)
    # a batch of batches (vmap of vmap), and a flag shared by the batch
    np.testing.assert_allclose(jax.vmap(jax.vmap(_scan))(needed.reshape(5, 1, 40), xs.reshape(5, 1, 40))[:, 0],
                               expected, rtol=1e-12)
    shared = jax.vmap(_scan, in_axes=(None, 0))(needed[0], xs)
    np.testing.assert_allclose(shared[0], expected[0], rtol=1e-12)


def _callbacks_in_a_batch():
    """How many times the function runs in a batch of 4 drives x 30 samples where two samples need it."""
    calls = []

    def counted(x):
        jax.debug.callback(lambda: calls.append(1))
        return _widths(x)

    needed = np.zeros((4, 30), bool)
    needed[1, 7] = needed[3, 7] = needed[0, 20] = True  # two samples of the batch need it
    jax.block_until_ready(jax.jit(jax.vmap(functools.partial(_scan, fn=counted)))(needed, np.ones((4, 30))))
    return len(calls)


def test_a_sample_no_drive_needs_does_not_compute_it():
    assert _callbacks_in_a_batch() == 2


def test_off_xla_cpu_it_is_the_plain_selection(monkeypatch):
    """An accelerator would read the cond's predicate back every step: there the function runs on every sample."""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert _callbacks_in_a_batch() >= 30


def test_it_passes_no_derivative_and_leaves_the_others_intact():
    xs = jnp.linspace(0.1, 1.0, 12)
    needed = xs > 0.5

    def loss(p, flags, values):
        def body(total, sample):
            flag, x = sample
            return total + p * x + where_needed(flag, _widths, p * x)[0], None
        return lax.scan(jax.checkpoint(body), 0.0, (flags, values))[0]

    assert np.isclose(jax.grad(loss)(2.0, needed, xs), float(xs.sum()), rtol=1e-12)
    batched = jax.grad(lambda p: jax.vmap(loss, (None, 0, 0))(p, jnp.stack([needed, ~needed]),
                                                             jnp.stack([xs, xs])).sum())(2.0)
    assert np.isclose(batched, 2 * float(xs.sum()), rtol=1e-12)
    _, tangent = jax.jvp(lambda p: jax.vmap(loss, (None, 0, 0))(p, needed[None], xs[None]), (2.0,), (1.0,))
    assert np.isclose(tangent[0], float(xs.sum()), rtol=1e-12)
