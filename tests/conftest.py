"""Test configuration: float64 and strict rank promotion, as in diffrax."""

from pathlib import Path

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REAL_DATA = SHARED / "data" / "real"


@pytest.fixture(scope="session")
def real_data_dir():
    if not REAL_DATA.is_dir():
        pytest.skip(f"real logs not available: {REAL_DATA} is absent (they live in ../shared, outside the repo)")
    return REAL_DATA
