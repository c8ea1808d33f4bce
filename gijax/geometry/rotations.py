"""Rotation helpers: axis-angle (rotation vector) to matrix, traceable and differentiable (also at
the zero rotation).

Quaternions enter gijax only from calibration files, where :mod:`gijax.io.rigfile` reads them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array


def skew(w: Array) -> Array:
    """(..., 3) -> (..., 3, 3) cross-product matrix."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2
    )


def axis_angle_to_matrix(w: Array) -> Array:
    """Rodrigues' formula with a Taylor branch near zero so the gradient at w = 0 is exact."""
    w = jnp.asarray(w)
    t2 = jnp.sum(w * w, axis=-1)[..., None, None]
    small = t2 < 1e-8
    t2s = jnp.where(small, 1.0, t2)
    t = jnp.sqrt(t2s)
    a = jnp.where(small, 1.0 - t2 / 6.0, jnp.sin(t) / t)
    b = jnp.where(small, 0.5 - t2 / 24.0, (1.0 - jnp.cos(t)) / t2s)
    k = skew(w)
    eye = jnp.eye(3, dtype=w.dtype)
    return eye + a * k + b * (k @ k)
