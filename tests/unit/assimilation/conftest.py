"""Fixtures of the forward operator's tests."""

import jax
import pytest


@pytest.fixture
def x64():
    """float64 inside the test only (derivative checks against finite differences)."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", old)
