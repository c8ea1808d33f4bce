"""Evenly spaced (EV) and closed-form geometry-informed (GI) distance candidates.

Both return 1-D ascending distances in metres, shape (n,), with the end points exactly
``d_min`` and ``d_max``; float64 when x64 is enabled, float32 otherwise.

EV: the inverse distances ``1/d_i`` are evenly spaced from ``1/d_min`` to ``1/d_max``.

GI (closed form): a point at distance ``d`` on a ray perpendicular to a baseline ``b`` is seen
from the other end of the baseline at the parallax angle ``theta(d) = atan(b / d)``. Equal
steps of that angle, ``theta_i = linspace(atan(b/d_min), atan(b/d_max), n)``, give
``d_i = b / tan(theta_i)``. With ``b = 0.3095015413531889`` this is the paper's released G16/G8.
"""

from __future__ import annotations

import jax.numpy as jnp

from gijax.candidates.validation import check_baseline, check_count, check_range
from gijax.geometry.layouts import TRAIN_BASELINE


def _float_dtype():
    return jnp.result_type(float)


def _pin_ends(d, d_min, d_max):
    """Replace the two end points by the exact range limits (no round-off at the ends)."""
    return d.at[0].set(d_min).at[-1].set(d_max)


def ev_candidates(n: int, d_min=0.5, d_max=100.0):
    """n distances (m), ascending, evenly spaced in inverse distance between 1/d_min and 1/d_max.

    Traceable in ``d_min`` and ``d_max`` (``n`` is static); the range is checked eagerly when
    concrete, by a checkify debug check when traced.
    """
    n = check_count(n)
    check_range(d_min, d_max)
    dt = _float_dtype()
    d_min = jnp.asarray(d_min, dt)
    d_max = jnp.asarray(d_max, dt)
    t = jnp.linspace(0.0, 1.0, n, dtype=dt)
    inv = 1.0 / d_min + t * (1.0 / d_max - 1.0 / d_min)
    return _pin_ends(1.0 / inv, d_min, d_max)


def gi_candidates(n: int, d_min=0.5, d_max=100.0, baseline=TRAIN_BASELINE):
    """n distances (m), ascending, with equal parallax-angle steps for one perpendicular baseline.

    ``baseline`` in metres. ``theta_i = linspace(atan(b/d_min), atan(b/d_max), n)``,
    ``d_i = b / tan(theta_i)``. Traceable (jit, vmap, grad) in ``baseline``, ``d_min`` and
    ``d_max`` (``n`` is static); the arguments are checked eagerly when concrete, by checkify
    debug checks when traced.
    """
    n = check_count(n)
    check_range(d_min, d_max)
    check_baseline(baseline)
    dt = _float_dtype()
    b = jnp.asarray(baseline, dt)
    d_min = jnp.asarray(d_min, dt)
    d_max = jnp.asarray(d_max, dt)
    theta = jnp.linspace(jnp.arctan(b / d_min), jnp.arctan(b / d_max), n)
    return _pin_ends(b / jnp.tan(theta), d_min, d_max)


def closed_form_steps(candidates, baseline):
    """Parallax-angle step (radians) between consecutive candidates for one perpendicular baseline.

    ``candidates`` (n,) metres ascending, ``baseline`` metres -> (n-1,) positive angles
    ``atan(b/d_i) - atan(b/d_{i+1})``: the feature displacement per step the paper plots.
    """
    d = jnp.asarray(candidates)
    theta = jnp.arctan(baseline / d)
    return theta[:-1] - theta[1:]
