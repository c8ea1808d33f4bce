"""Training losses on panoramas of distance: pure, jit-able, differentiable functions.

Shapes: probabilities ``prob`` (B, D, H, W) over the D candidates (softmax along axis 1);
predicted inverse distance ``inv_pred`` (B, H, W) in 1/m; label ``distance`` (B, H, W) in
metres (sky / no hit stored as a huge distance, 1e6 m); ``valid`` (B, H, W) bool or {0, 1};
``candidates`` (D,) ascending distances in metres.

Labels are clamped to the candidate range in inverse distance (a label farther than the last
candidate counts as the last candidate, one nearer than the first as the first), because the
network can only express inverse distances between those of its candidates. A pixel counts
when ``valid`` is set and its label is usable (:func:`gijax.evaluate.labels.usable_label`).

Computation is in float32, or float64 when the inputs are (:func:`gijax.numerics.float_dtype`).
Every function is traceable (jit, vmap, grad in the predictions and the candidates; a loss
``kind`` is static).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.evaluate.labels import clamped_inverse, label_mask
from gijax.numerics import float_dtype

Array = jax.Array

# The released network regresses 96 / d; the smooth L1 loss is evaluated in those units so its
# beta = 1 transition sits where it did in the release.
RELEASE_INV_SCALE = 96.0

# Smallest probability fed to a logarithm: keeps log(0) finite (log(1e-30) = -69) with a zero
# gradient through the clamp, and is representable in float32 and bfloat16 alike.
_PROB_FLOOR = 1e-30


def two_hot_target(distance: Array, candidates: Array) -> Array:
    """(B, D, H, W) two-hot target, linear in inverse distance between the bracketing candidates.

    For a clamped label ``x = 1/d`` between the inverse candidates ``q_a >= x >= q_b`` of two
    neighbouring candidates ``a, b = a + 1``, the target puts ``(x - q_b) / (q_a - q_b)`` on
    ``a`` and the rest on ``b``; every target sums to 1 and reproduces ``x`` as ``sum_i t_i q_i``.
    """
    cand = jnp.asarray(candidates, float_dtype(distance, candidates))
    n = cand.shape[0]
    inv_c = 1.0 / cand                                   # descending with ascending distance
    x = clamped_inverse(distance, cand)[:, None]         # (B, 1, H, W)
    # Index a of the nearer bracketing candidate: the last one whose inverse is still >= x,
    # kept in [0, D-2] so that a + 1 exists.
    count = jnp.sum(inv_c[None, :, None, None] >= x, axis=1)        # (B, H, W)
    a = jnp.clip(count - 1, 0, n - 2)
    q_a = inv_c[a][:, None]
    q_b = inv_c[a + 1][:, None]
    w_a = jnp.clip((x - q_b) / (q_a - q_b), 0.0, 1.0)                # (B, 1, H, W)
    idx = jnp.arange(n)[None, :, None, None]
    a4 = a[:, None]
    return jnp.where(idx == a4, w_a, 0.0) + jnp.where(idx == a4 + 1, 1.0 - w_a, 0.0)


def volume_loss(prob: Array, distance: Array, valid: Array, candidates: Array) -> Array:
    """Binary cross-entropy between softmax probabilities and the two-hot target (scalar).

    ``mean over usable pixels and candidates of -[t log p + (1 - t) log(1 - p)]``. Pixels whose
    label is unusable are excluded from both the sum and the count (the release averages over
    all pixels because its labels are always valid; on such data the two agree). Returns 0 when
    no pixel is usable.
    """
    t = two_hot_target(distance, candidates)
    p = prob.astype(float_dtype(prob, t))
    m = label_mask(distance, valid)[:, None]                       # (B, 1, H, W)
    bce = -(t * jnp.log(jnp.maximum(p, _PROB_FLOOR))
            + (1.0 - t) * jnp.log(jnp.maximum(1.0 - p, _PROB_FLOOR)))
    count = jnp.sum(m) * p.shape[1]
    return jnp.sum(bce * m) / jnp.maximum(count, 1.0)


def smooth_l1(x: Array, beta: float = 1.0) -> Array:
    """Elementwise smooth L1 (Huber / beta): 0.5 x^2 / beta for |x| < beta, else |x| - beta / 2."""
    ax = jnp.abs(x)
    return jnp.where(ax < beta, 0.5 * x * x / beta, ax - 0.5 * beta)


def smooth_l1_loss(inv_pred: Array, distance: Array, valid: Array, candidates: Array,
                   beta: float = 1.0, scale: float = RELEASE_INV_SCALE) -> Array:
    """Mean smooth L1 between ``scale * inv_pred`` and ``scale / d`` over usable pixels (scalar).

    ``inv_pred`` is in 1/m; both sides are multiplied by ``scale`` (96, the release's units)
    before the loss; the label is clamped to the candidate range. Returns 0 when no pixel is
    usable.
    """
    target = clamped_inverse(distance, candidates)
    m = label_mask(distance, valid)
    err = smooth_l1(scale * (inv_pred.astype(float_dtype(inv_pred, target)) - target), beta)
    return jnp.sum(err * m) / jnp.maximum(jnp.sum(m), 1.0)


def model_loss(kind: str, outputs: dict, distance: Array, valid: Array, candidates: Array) -> Array:
    """The loss a model configuration asks for: ``'volume'`` or ``'smooth_l1'``. A model with
    the guided refinement (its outputs hold ``inv_distance_coarse``) adds the smooth L1 of its
    refined ``inv_distance`` to the volume loss (the smooth-L1 loss is on it already)."""
    if kind == "volume":
        loss = volume_loss(outputs["prob"], distance, valid, candidates)
        if "inv_distance_coarse" in outputs:
            loss = loss + smooth_l1_loss(outputs["inv_distance"], distance, valid, candidates)
        return loss
    if kind == "smooth_l1":
        return smooth_l1_loss(outputs["inv_distance"], distance, valid, candidates)
    raise ValueError(f"unknown loss {kind!r}; expected 'volume' or 'smooth_l1'")
