"""What counts as a usable label, and the label forms the losses and metrics score against.

A label is a distance in metres per panorama pixel. It is usable where it is a finite
positive number: sky, stored as a huge distance (1e6 m), is usable; NaN, inf, 0 and negative
values (no label was recorded there) are not. Every loss, metric and evaluation decides this
through :func:`usable_label`; the prediction files and point clouds apply the same rule to a
predicted distance (one that is not usable is written as invalid).

:func:`usable_label` keeps the array kind it is given (NumPy in, NumPy out, so the data
loader stays on the host; a JAX array or tracer in, a JAX array out). The other functions are
traceable (jit, vmap, grad in the distances and candidates).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from gijax.numerics import float_dtype

Array = jax.Array


def usable_label(distance):
    """Bool mask, same shape as ``distance``: True where the label is finite and positive."""
    xp = jnp if isinstance(distance, jax.Array) else np
    return xp.isfinite(distance) & (distance > 0)


def label_mask(distance: Array, valid: Array) -> Array:
    """float32 of ``distance``'s shape: 1 where ``valid`` is set and the label is usable."""
    valid = valid.astype(bool) if valid.dtype != bool else valid
    return (valid & usable_label(jnp.asarray(distance))).astype(jnp.float32)


def clamped_inverse(distance: Array, candidates: Array) -> Array:
    """Inverse label distance (1/m), clamped to [1/candidates[-1], 1/candidates[0]].

    Unusable labels map to the far end so the result stays finite; callers mask them out with
    :func:`label_mask`.
    """
    dt = float_dtype(distance, candidates)
    cand = jnp.asarray(candidates, dt)
    lo, hi = 1.0 / cand[-1], 1.0 / cand[0]
    distance = jnp.asarray(distance)
    d = jnp.where(usable_label(distance), distance, cand[-1]).astype(dt)
    return jnp.clip(1.0 / d, lo, hi)
