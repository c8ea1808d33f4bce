"""Shared test setup: float64 is enabled per test with ``jax.enable_x64`` where a test needs it."""

import os

# Keep XLA from grabbing every core twice when pytest-xdist runs two workers on a 2-core box.
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")
