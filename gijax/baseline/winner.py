"""Winner-take-all over the candidates, parabola refinement, and conversion to distance.

The fractional index ``k + delta`` (``delta = 0.5 (L - R) / (L + R - 2 C)`` clamped to
[-0.5, 0.5], with C the cost at the winner k and L, R its neighbours) is turned into an
inverse distance by linear interpolation in the actual candidate list, in inverse distance:
``inv = (1 - f) / d_i + f / d_{i+1}`` with ``i = floor(k + delta)``, ``f`` the fraction. For
evenly spaced inverse candidates this equals the usual closed form; for any other list
(geometry-informed candidates) it is the only correct conversion.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array


def parabola_offset(left: Array, centre: Array, right: Array) -> Array:
    """Sub-candidate offset of the minimum of the parabola through three costs, in [-0.5, 0.5].

    0 where the three costs are not strictly convex (no finite minimum).
    """
    den = left + right - 2.0 * centre
    ok = den > 1e-12
    off = 0.5 * (left - right) / jnp.where(ok, den, 1.0)
    return jnp.where(ok, jnp.clip(off, -0.5, 0.5), 0.0)


def index_to_inverse_distance(index: Array, candidates: Array) -> Array:
    """Fractional candidate index (...) -> inverse distance (1/m), linear in 1/d between entries."""
    inv = 1.0 / candidates
    n = candidates.shape[0]
    index = jnp.clip(index, 0.0, n - 1.0)
    i0 = jnp.clip(jnp.floor(index).astype(jnp.int32), 0, n - 2)
    frac = index - i0
    return (1.0 - frac) * inv[i0] + frac * inv[i0 + 1]


def winner_take_all(cost: Array, candidates: Array) -> dict:
    """Cost (D, H, W) and candidates (D,) -> dict(index, fractional index, inv_distance, cost).

    At the first and last candidate no refinement is applied (one neighbour is missing).
    """
    d = cost.shape[0]
    k = jnp.argmin(cost, axis=0)
    centre = jnp.take_along_axis(cost, k[None], 0)[0]
    left = jnp.take_along_axis(cost, jnp.maximum(k - 1, 0)[None], 0)[0]
    right = jnp.take_along_axis(cost, jnp.minimum(k + 1, d - 1)[None], 0)[0]
    inner = (k > 0) & (k < d - 1)
    offset = jnp.where(inner, parabola_offset(left, centre, right), 0.0)
    frac_index = k.astype(cost.dtype) + offset
    return dict(index=k, frac_index=frac_index,
                inv_distance=index_to_inverse_distance(frac_index, candidates), cost=centre)
