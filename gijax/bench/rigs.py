"""Rigs and inputs for the benchmark cases: regular-polygon layouts of any camera count and
random network inputs of a preset's sizes."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from gijax.geometry.layouts import layout_rig
from gijax.geometry.rig import Rig, scale_rig
from gijax.nn.presets import ModelConfig

# The paper's test layouts put neighbouring cameras 1 m apart (REFERENCE section 6, Table II).
POLYGON_SIDE = 1.0


def polygon_positions(n: int, side: float = POLYGON_SIDE) -> np.ndarray:
    """(n, 3) camera centres on a regular n-gon of edge ``side`` metres in the z = 0 plane,
    the first at +y (as the built-in triangle)."""
    if int(n) != n or n < 2:
        raise ValueError(f"a polygon rig needs an integer camera count >= 2; found {n!r}")
    if not side > 0:
        raise ValueError(f"polygon side must be positive metres; found {side!r}")
    radius = side / (2.0 * math.sin(math.pi / n)) if n > 2 else side / 2.0
    angles = np.deg2rad(90.0 + 360.0 * np.arange(n) / n)
    return np.stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(n)], -1)


def polygon_rig(n: int, side: float = POLYGON_SIDE, image_scale: float = 1.0) -> Rig:
    """The synthetic-lens rig on a regular n-gon (reference at the centroid), images scaled by
    ``image_scale``, without static masks (benchmarks feed per-sample masks)."""
    p = polygon_positions(n, side)
    rig = layout_rig(p, p.mean(0), masks=False)
    return rig if image_scale == 1.0 else scale_rig(rig, image_scale)


def network_rig(rig: Rig, config: ModelConfig) -> Rig:
    """``rig`` at the network's image size, static masks dropped (they are per-sample inputs)."""
    if config.image_scale != 1.0:
        rig = scale_rig(rig, config.image_scale)
    return rig.replace(masks=tuple(None for _ in rig.masks))


def with_candidates(config: ModelConfig, n: int) -> ModelConfig:
    """``config`` with ``n`` candidates (the structure otherwise unchanged)."""
    return dataclasses.replace(config, name=f"{config.name}@D{n}", num_candidates=int(n))


def network_inputs(config: ModelConfig, cameras: int, batch: int = 1, seed: int = 0) -> tuple:
    """Random surrogate images (B, N, Hs, Ws, 3) in [0, 1], all-ones masks (B, N, Hs, Ws) and
    geometric candidates (D,) metres from d_min to d_max, float32."""
    hs, ws = config.surrogate_hw
    rng = np.random.default_rng(seed)
    sur = jnp.asarray(rng.uniform(size=(batch, cameras, hs, ws, 3)), jnp.float32)
    masks = jnp.ones((batch, cameras, hs, ws), jnp.float32)
    cand = jnp.asarray(np.geomspace(config.d_min, config.d_max, config.num_candidates),
                       jnp.float32)
    return sur, masks, cand
