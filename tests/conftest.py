"""Shared test fixtures. float64 is enabled per test with ``jax.enable_x64`` where needed."""

import jax
import pytest


@pytest.fixture(scope="module")
def quick_compiles():
    """Compile without XLA's optimisation passes, for modules whose checks (shapes,
    invariances, gradients, errors, files) do not depend on them: they dominate compile time."""
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", True)
    yield
    jax.config.update("jax_disable_most_optimizations", previous)
