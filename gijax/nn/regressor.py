"""Soft-argmax regression of distance from the U-Net logits.

The (B, D, h, w) logits are upsampled bilinearly x2 (align_corners=False) to the output size
(or used as they are when the output has the logits' size, ``output_stride`` 1) BEFORE the
softmax over the D candidates (as in the release: interpolating logits keeps sharp,
multi-modal distributions that interpolating probabilities would blur). The estimate is the
expectation of inverse distance, ``inv = sum_i p_i / d_i`` (1/m), which is what the candidates
are (near-)uniform in; ``distance = 1 / inv`` (m). The per-pixel entropy
``-sum_i p_i log p_i`` (nats, 0 .. log D) serves as the uncertainty.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

from gijax.nn.upsample import upsample2

Array = jax.Array


def regress(logits: Array, candidates: Array, output_hw: Sequence[int]) -> dict[str, Array]:
    """Logits (B, D, h, w), candidates (D,) ascending metres, output_hw = (2h, 2w) or (h, w) ->
    dict(inv_distance (B, H, W) 1/m, distance (B, H, W) m, prob (B, D, H, W),
    entropy (B, H, W) nats)."""
    if logits.ndim != 4:
        raise ValueError(f"regress: logits must be (B, D, h, w), got {logits.shape}")
    b, d, h, w = logits.shape
    if candidates.shape != (d,):
        raise ValueError(
            f"regress: candidates must have shape ({d},) to match the logits, got "
            f"{candidates.shape}"
        )
    if tuple(output_hw) not in ((2 * h, 2 * w), (h, w)):
        raise ValueError(
            f"regress: output_hw must be twice the logits' (h, w) = {(2 * h, 2 * w)} or equal "
            f"to it, got {tuple(output_hw)}"
        )
    up = logits if tuple(output_hw) == (h, w) else upsample2(logits, (2, 3))
    log_p = jax.nn.log_softmax(up, axis=1)
    prob = jnp.exp(log_p)
    inv_cand = (1.0 / candidates).astype(up.dtype)
    inv = jnp.einsum("bdhw,d->bhw", prob, inv_cand)
    entropy = -jnp.sum(prob * log_p, axis=1)
    return {"inv_distance": inv, "distance": 1.0 / inv, "prob": prob, "entropy": entropy}
