"""Random numbers addressed by name, so that adding a draw never changes another one.

A generator asks for numbers by name, ``draws.uniform("pole/radius", (6,), 0.02, 0.15)``.
Element ``i`` (row-major) of the draw ``name`` is

    uniform(fold_in(fold_in(key, crc32(name)), i))

a function of the key, the name and the index only. Adding, removing or resizing a draw leaves
the numbers of every other draw as they were, so a scene generator can grow without
reshuffling the scenes of every seed (as a pool consumed in call order would).

Giving every draw its own ``jax.random`` call would put one counter-based generator per draw
into the compiled program, and a scene has about two hundred draws: that compiles for tens of
seconds on a CPU. :func:`run_with_draws` therefore runs a program twice: once on abstract
values (``jax.eval_shape``, nothing is computed) to record the names and shapes it asks for,
then for real, with every number made by one batched generator call.
"""

from __future__ import annotations

import functools
import math
import zlib
from typing import Callable, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array
T = TypeVar("T")


def name_hash(name: str) -> np.uint32:
    """A stable 32-bit number for ``name`` (CRC-32 of its UTF-8 bytes; Python's ``hash`` of a
    string changes between processes)."""
    return np.uint32(zlib.crc32(name.encode("utf-8")))


def named_key(key: Array, name: str) -> Array:
    """The key of ``name`` derived from ``key``: independent of every other name's key."""
    return jax.random.fold_in(key, name_hash(name))


def _shape(shape) -> tuple:
    """A shape as a tuple of ints (an int ``n`` is the shape ``(n,)``)."""
    return tuple(int(n) for n in shape) if isinstance(shape, (tuple, list)) else (int(shape),)


def _size(shape: tuple) -> int:
    return int(math.prod(shape))


def _uniforms(key: Array, requests: dict[str, tuple]) -> dict[str, Array]:
    """Every requested draw, made by one batched generator call per stage."""
    if not requests:
        return {}
    names = list(requests)
    sizes = [_size(requests[n]) for n in names]
    hashes = np.array([name_hash(n) for n in names], np.uint32)
    if len(set(hashes.tolist())) < len(names):
        # Two names with one CRC-32 would get the same numbers; rename one of them.
        raise ValueError(f"random draw names with the same hash among {names}")
    owner = np.repeat(np.arange(len(names)), sizes)
    index = np.concatenate([np.arange(s, dtype=np.uint32) for s in sizes])
    name_keys = jax.vmap(jax.random.fold_in, (None, 0))(key, hashes)
    element_keys = jax.vmap(jax.random.fold_in)(name_keys[owner], index)
    flat = jax.vmap(lambda k: jax.random.uniform(k, (), jnp.float32))(element_keys)
    bounds = np.cumsum([0] + sizes)
    return {n: flat[bounds[i]:bounds[i + 1]].reshape(requests[n]) for i, n in enumerate(names)}


def named_uniform(key: Array, name: str, shape: tuple = ()) -> Array:
    """The numbers of the draw ``name`` alone: equal to what :class:`Draws` gives that name."""
    return _named_uniform(key, name, _shape(shape))


@functools.partial(jax.jit, static_argnames=("name", "shape"))
def _named_uniform(key: Array, name: str, shape: tuple) -> Array:
    # Jitted: run eagerly, each of its operations would be compiled on its own, which is slower.
    return _uniforms(key, {name: shape})[name]


class Draws:
    """The named uniform draws of one program run; see the module docstring.

    ``scope("indoor")`` returns a view whose names are prefixed with ``"indoor/"``, so the same
    sub-generator can run in two places with independent numbers.
    """

    def __init__(self, source: Callable[[str, tuple], Array], prefix: str = ""):
        self._source = source
        self._prefix = prefix

    def scope(self, name: str) -> "Draws":
        return Draws(self._source, f"{self._prefix}{name}/")

    def __call__(self, name: str, shape=()) -> Array:
        """Uniform numbers in [0, 1) of ``shape``."""
        return self._source(self._prefix + name, _shape(shape))

    def uniform(self, name: str, shape=(), lo=0.0, hi=1.0) -> Array:
        return lo + (hi - lo) * self(name, shape)

    def log_uniform(self, name: str, shape, lo: float, hi: float) -> Array:
        """Log-uniform in [lo, hi): every octave of scale is as likely."""
        return jnp.exp(self.uniform(name, shape, math.log(lo), math.log(hi)))

    def bernoulli(self, name: str, p: float, shape=()) -> Array:
        return self(name, shape) < p

    def randint(self, name: str, shape, lo: int, hi: int) -> Array:
        """Integers in [lo, hi)."""
        return jnp.minimum(lo + jnp.floor(self(name, shape) * (hi - lo)).astype(jnp.int32),
                           hi - 1)

    def normal(self, name: str, shape) -> Array:
        """Standard normal numbers by the Box-Muller transform of one draw of shape (2, *shape)."""
        u = self(name, (2,) + _shape(shape))
        radius = jnp.sqrt(-2.0 * jnp.log(jnp.maximum(u[0], 1e-7)))
        return radius * jnp.cos(2.0 * jnp.pi * u[1])

    def count_mask(self, name: str, n: int, lo: int, hi: int) -> Array:
        """(n,) bool with a random number in [lo, hi] of leading slots set."""
        return jnp.arange(n) < self.randint(name, (), lo, hi + 1)

    def polar(self, name: str, shape, rho) -> Array:
        """Horizontal positions (*shape, 2) at distance ``rho`` from the axis, random azimuth."""
        ang = self.uniform(name, shape, -math.pi, math.pi)
        return jnp.stack([rho * jnp.cos(ang), rho * jnp.sin(ang)], -1)


def run_with_draws(key: Array, program: Callable[[Draws], T]) -> T:
    """``program(draws)`` (a pytree of arrays) with its named draws made from ``key``.

    The program must ask for the same names and shapes on every run (they are fixed by Python
    control flow, never by drawn values) and may ask for each name only once.
    """
    requests: dict[str, tuple] = {}

    def record(name: str, shape: tuple) -> Array:
        if name in requests:
            raise ValueError(f"the random draw {name!r} is asked for twice; names must be unique")
        requests[name] = shape
        return jnp.zeros(shape, jnp.float32)

    jax.eval_shape(lambda: program(Draws(record)))
    table = _uniforms(key, requests)
    return program(Draws(lambda name, shape: table[name]))
