"""Regression of distance from the U-Net logits: the soft-argmax or the sub-pixel mode.

The (B, D, h, w) logits are upsampled bilinearly x2 (align_corners=False) to the output size
(or used as they are when the output has the logits' size, ``output_stride`` 1) BEFORE the
softmax over the D candidates (as in the release: interpolating logits keeps sharp,
multi-modal distributions that interpolating probabilities would blur). The estimate is the
expectation of inverse distance, ``inv = sum_i p_i / d_i`` (1/m), which is what the candidates
are (near-)uniform in; ``distance = 1 / inv`` (m). The per-pixel entropy
``-sum_i p_i log p_i`` (nats, 0 .. log D) serves as the uncertainty.

Two estimates (``estimate``):

* ``'mean'`` (the paper's and the release's): the expectation over all D candidates. Where the
  distribution has two modes (a pixel on an occlusion boundary sees a near and a far surface) it
  lands between them, on neither surface.
* ``'mode'``: the sub-pixel mode (Tulyakov et al., "Practical Deep Stereo", NeurIPS 2018, their
  sub-pixel MAP): the expectation over the candidates within ``window`` of the most probable
  one, renormalised, so a two-mode pixel takes the stronger surface with sub-candidate
  precision. The window's choice is piecewise constant in the logits (no gradient flows through
  it); inside it the estimate is differentiable like the mean. It is built from a maximum and
  shifted comparisons, not an arg-max, so that it exports to ONNX / TensorRT as elementwise ops;
  where two candidates tie for the maximum, the window covers both neighbourhoods.

  Which candidate is "most probable" is read at ``pick`` (gijax's option; 0 by default,
  Tulyakov's rule): the candidate whose neighbourhood of ``pick`` candidates on each
  side holds the most probability. A surface between two candidates splits its probability
  between them, so with dense candidates a false match concentrated on one candidate can
  out-peak the true surface while holding less probability (seen on a 32-candidate network:
  0.30 on one candidate against 0.24 + 0.29 on the true surface's two); ``pick`` 1 takes the
  surface with the most probability.

The probabilities, the entropy and the volume loss do not depend on the estimate, so a model
trained with the volume loss can be read with either.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

from gijax.nn.upsample import upsample2

Array = jax.Array

ESTIMATES = ("mean", "mode")


def check_estimate(estimate: str, window: int = 0, pick: int = 0) -> None:
    """ValueError (one line) unless ``estimate`` is one of :data:`ESTIMATES` and ``window``
    and ``pick`` non-negative numbers of candidates."""
    if estimate not in ESTIMATES:
        raise ValueError(f"estimate must be one of {ESTIMATES}; found {estimate!r}")
    if window < 0:
        raise ValueError(f"the mode's window must be >= 0 candidates; found {window}")
    if pick < 0:
        raise ValueError(f"the mode's pick must be >= 0 candidates; found {pick}")


def _shifted(x: Array, shift: int, fill) -> tuple[Array, Array]:
    """``x`` moved ``shift`` places down and up axis 1, the vacated places set to ``fill``."""
    pad = jnp.full_like(x[:, :shift], fill)
    return (jnp.concatenate([pad, x[:, :-shift]], axis=1),
            jnp.concatenate([x[:, shift:], pad], axis=1))


def mode_window_mask(prob: Array, window: int, pick: int = 0) -> Array:
    """(B, D, H, W) bool: candidates within ``window`` places of a most probable one along
    axis 1, "most probable" meaning the most probability within ``pick`` places on each side
    (no gradient; see the module docstring)."""
    prob = jax.lax.stop_gradient(prob)
    d = prob.shape[1]
    mass = prob
    for shift in range(1, min(pick, d - 1) + 1):
        down, up = _shifted(prob, shift, 0.0)
        mass = mass + down + up
    top = mass >= jnp.max(mass, axis=1, keepdims=True)
    mask = top
    for shift in range(1, min(window, d - 1) + 1):
        down, up = _shifted(top, shift, False)
        mask = mask | down | up
    return mask


def estimate_inverse(prob: Array, inv_cand: Array, estimate: str = "mean",
                     window: int = 2, pick: int = 0) -> Array:
    """Inverse distance (B, H, W) from probabilities (B, D, H, W) over candidates whose
    inverses are ``inv_cand`` (D,): their expectation (``'mean'``) or the sub-pixel mode
    (``'mode'``: the expectation within ``window`` candidates of the most probable one, read
    at ``pick``; see the module docstring)."""
    check_estimate(estimate, window, pick)
    if estimate == "mean":
        return jnp.einsum("bdhw,d->bhw", prob, inv_cand)
    kept = jnp.where(mode_window_mask(prob, window, pick), prob, 0.0)
    return jnp.einsum("bdhw,d->bhw", kept, inv_cand) / jnp.sum(kept, axis=1)


def regress(logits: Array, candidates: Array, output_hw: Sequence[int], estimate: str = "mean",
            window: int = 2, pick: int = 0) -> dict[str, Array]:
    """Logits (B, D, h, w), candidates (D,) ascending metres, output_hw = (2h, 2w) or (h, w) ->
    dict(inv_distance (B, H, W) 1/m, distance (B, H, W) m, prob (B, D, H, W),
    entropy (B, H, W) nats); ``estimate``, ``window`` and ``pick`` as
    :func:`estimate_inverse` takes them."""
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
    inv = estimate_inverse(prob, inv_cand, estimate, window, pick)
    entropy = -jnp.sum(prob * log_p, axis=1)
    return {"inv_distance": inv, "distance": 1.0 / inv, "prob": prob, "entropy": entropy}
