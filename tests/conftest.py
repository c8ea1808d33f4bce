"""Shared test fixtures. float64 is enabled per test with ``jax.enable_x64`` where needed."""

import os

import jax
import pytest


# Modules whose module-scoped fixtures take tens of seconds (the experiments' smoke runs, the
# ONNX exports, the multi-device training): their tests stay on one xdist worker
# (``--dist loadgroup``), so the fixture is built once; every other test is balanced alone.
SHARED_FIXTURE_MODULES = ("test_experiments", "test_export", "test_train_parallel")


def pytest_collection_modifyitems(config, items):
    """Tests marked ``long`` (extra seeds of the fault probe) run only with GIJAX_LONG_TESTS=1,
    so the default suite stays within its time budget; the tests of
    :data:`SHARED_FIXTURE_MODULES` share one worker per module."""
    for item in items:
        module = item.module.__name__.rsplit(".", 1)[-1] if item.module else ""
        if module in SHARED_FIXTURE_MODULES:
            item.add_marker(pytest.mark.xdist_group(module))
    if os.environ.get("GIJAX_LONG_TESTS") == "1":
        return
    skip = pytest.mark.skip(reason="long variant: set GIJAX_LONG_TESTS=1 to run it")
    for item in items:
        if "long" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="module")
def quick_compiles():
    """Compile without XLA's optimisation passes, for modules whose checks (shapes,
    invariances, gradients, errors, files) do not depend on them: they dominate compile time."""
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", True)
    yield
    jax.config.update("jax_disable_most_optimizations", previous)
