"""The normal equations as named sums, solved by a Cholesky factor written out (jaxmodel/normal_equations.py)."""

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxmodel import normal_equations as ne


@settings(max_examples=30, deadline=None)
@given(k=st.integers(1, 6), seed=st.integers(0, 10_000), ridge=st.floats(0.0, 10.0))
def test_solves_like_numpy(k, seed, ridge):
    """The sums of a random weighted regression, plus a ridge, solved as numpy solves them; y and L as documented."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(40, k))
    w = rng.uniform(0.1, 2.0, 40)
    y_obs = rng.normal(size=40)
    normal = (x * w[:, None]).T @ x
    rhs = (x * w[:, None]).T @ y_obs
    fields = NamedTuple("F", [(n, float) for n in ne.sum_fields(k)])(
        *[normal[i, j] for i, j in ne.pairs(k)], *rhs)
    m = ne.normal_matrix(fields, k, [ridge] * k)
    c, y, low = ne.cholesky_solve([[jnp.asarray(v) for v in row] for row in m], [jnp.asarray(v) for v in rhs])
    expected = np.linalg.solve(normal + ridge * np.eye(k), rhs)
    np.testing.assert_allclose(np.array(c, float), expected, rtol=1e-9, atol=1e-12)
    factor = np.array([[float(low[i][j]) if j <= i else 0.0 for j in range(k)] for i in range(k)])
    np.testing.assert_allclose(factor @ factor.T, normal + ridge * np.eye(k), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(factor @ np.array(y, float), rhs, rtol=1e-9, atol=1e-12)


def test_names_and_pairs():
    assert ne.pairs(3) == [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    assert ne.sum_fields(2) == ["n00", "n01", "n11", "b0", "b1"]
