"""Guarded elementary operations: sqrt, division and norms that stay finite, with finite
gradients, at the degenerate inputs geometry meets (zero vectors, zero denominators).

Every guard is a ``jnp.where`` on the *input* of the unsafe operation, so the masked branch
never produces an inf or NaN whose cotangent would poison the gradient (``0 * inf = NaN``), and
the gradient is exactly zero where the guard replaced the value.

The threshold comes from the input's dtype (``jnp.finfo``), so the same code is as tight in
float64 as in float32: :func:`guard_floor` ``= sqrt(tiny)`` with ``tiny`` the smallest positive
normal number (1.1e-19 in float32, 1.5e-154 in float64). A denominator is never smaller than it,
so ``1 / den**2 <= 1 / tiny`` stays finite (the derivative of a quotient); a square root is
never taken of less than it, so the root is at least ``tiny**(1/4)`` and the root's own
reciprocal square is finite too (a guarded norm that ends up squared in a denominator).

Integer inputs are treated as JAX's default float type.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

Array = jax.Array

__all__ = ["tiny", "guard_floor", "safe_sqrt", "sqrt_or_zero", "safe_norm", "unit", "safe_div",
           "safe_denominator", "away_from_zero", "float_dtype"]


def _float_dtype(*xs) -> jnp.dtype:
    dtype = jnp.result_type(*xs)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    return dtype


def float_dtype(*xs) -> jnp.dtype:
    """The common dtype of ``xs`` widened to at least float32: float64 inputs stay float64,
    bfloat16 / float16 / integer / bool inputs compute in float32 (losses and metrics
    accumulate over many pixels, which half precision cannot)."""
    return jnp.promote_types(jnp.result_type(*xs), jnp.float32)


def tiny(*xs) -> float:
    """Smallest positive normal number of the (common, floating) dtype of ``xs``."""
    return float(jnp.finfo(_float_dtype(*xs)).tiny)


def guard_floor(*xs) -> float:
    """``sqrt(tiny)`` of the dtype of ``xs``: the smallest denominator :func:`safe_div` divides
    by and the smallest argument :func:`safe_sqrt` takes the root of (module docstring)."""
    return math.sqrt(tiny(*xs))


def safe_sqrt(x: Array) -> Array:
    """``sqrt(x)`` for ``x > guard_floor``, ``sqrt(guard_floor)`` below, with a zero gradient there.

    For quantities that are non-negative in exact arithmetic (squared norms, discriminants)
    where rounding or a degenerate input reaches zero or slightly below it, and that may end up
    in a denominator.
    """
    x = jnp.asarray(x, _float_dtype(x))
    f = guard_floor(x)
    return jnp.sqrt(jnp.where(x > f, x, f))


def sqrt_or_zero(x: Array) -> Array:
    """``sqrt(x)`` for ``x > guard_floor``, exactly 0 below, with a zero gradient there.

    For a length that is reported (an RMS error, a spacing) rather than divided by: 0 stays 0.
    Use :func:`safe_sqrt` for anything that may end up in a denominator.
    """
    x = jnp.asarray(x, _float_dtype(x))
    ok = x > guard_floor(x)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


def safe_norm(x: Array, axis: int | tuple[int, ...] = -1, keepdims: bool = False) -> Array:
    """Euclidean norm over ``axis``; ``sqrt(guard_floor)`` (not 0) and a zero gradient at the
    zero vector.

    ``jnp.linalg.norm`` has a NaN gradient at zero (``x / |x|`` with ``|x| = 0``).
    """
    x = jnp.asarray(x, _float_dtype(x))
    return safe_sqrt(jnp.sum(x * x, axis=axis, keepdims=keepdims))


def unit(x: Array, axis: int = -1) -> Array:
    """``x / |x|`` along ``axis``; the zero vector maps to the zero vector with a zero gradient."""
    x = jnp.asarray(x, _float_dtype(x))
    sq = jnp.sum(x * x, axis=axis, keepdims=True)
    ok = sq > guard_floor(x)
    return jnp.where(ok, x / jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def safe_div(num: Array, den: Array, fill: float = 0.0, floor: float | None = None) -> Array:
    """``num / den`` where ``|den| > floor``, ``fill`` elsewhere; the gradient is 0 there too.

    ``floor`` defaults to :func:`guard_floor` of the operands' dtype. A caller with a scale of
    its own (a denominator that is meaningless below a fraction of a metre, say) passes it.
    """
    dtype = _float_dtype(num, den)
    num, den = jnp.asarray(num, dtype), jnp.asarray(den, dtype)
    f = guard_floor(dtype) if floor is None else floor
    ok = jnp.abs(den) > f
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), jnp.asarray(fill, dtype))


def safe_denominator(den: Array) -> Array:
    """A non-negative normaliser (a sum of weights) with its zeros replaced by 1.

    ``sum(w x) / safe_denominator(sum(w))`` is the weighted mean wherever any weight is
    positive and 0 (the numerator) where every weight is 0.
    """
    den = jnp.asarray(den, _float_dtype(den))
    return jnp.where(den > guard_floor(den), den, 1.0)


def away_from_zero(x: Array, floor: float | None = None) -> Array:
    """``x`` with magnitudes at or below ``floor`` pushed out to ``+-floor`` (sign kept, 0 -> +).

    For slopes that are divided by later (a ray direction component in a slab or plane test)
    where the sign matters: ``1 / away_from_zero(d)`` is a huge number of the right sign
    instead of an inf. ``floor`` defaults to :func:`guard_floor` of the dtype.
    """
    x = jnp.asarray(x, _float_dtype(x))
    f = guard_floor(x) if floor is None else floor
    return jnp.where(jnp.abs(x) > f, x, jnp.where(x >= 0, f, -f))
