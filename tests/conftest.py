"""Shared test fixtures. float64 is enabled per test with ``jax.enable_x64`` where needed."""

import os

import jax
import pytest


def pytest_collection_modifyitems(config, items):
    """Tests marked ``long`` (extra seeds of the fault probe) run only with GIJAX_LONG_TESTS=1,
    so the default suite stays within its time budget.

    Modules whose module-scoped fixtures take tens of seconds (the experiments' smoke runs, the
    ONNX exports, the multi-device training) mark themselves ``xdist_group``: under
    ``--dist loadgroup`` their tests stay on one worker and the fixture is built once, while
    every other test is balanced on its own."""
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
