"""Named random streams: every random draw of the input pipeline and the trainer comes from a
stream named here, once.

A draw is a pure function of ``(seed, stream, counters...)``: the counters say where it happens
(epoch, sample index, step), so a resumed run draws what an uninterrupted one would, and the
stream's tag is mixed into the entropy, so two streams of one seed never coincide.
:func:`host_rng` gives a NumPy generator for draws made on the host (shuffling, the mixture's
folder choice, mask erasing); :func:`device_key` a JAX key for draws made in jitted code (pixel
augmentation, calibration errors). Both read the same entropy ``[seed, *counters, tag]``.
"""

from __future__ import annotations

import jax
import numpy as np

# Stream name -> tag (ASCII of a short name, so a tag reads as what it is in a hex dump).
STREAMS = {
    "shuffle": 0x73687566,      # 'shuf': the sample order of an epoch
    "mixture": 0x6D6978,        # 'mix': which training folder a step's batch comes from
    "erase": 0x6D61736B,        # 'mask': the rectangles erased from a sample's masks
    "pixels": 0x70697863,       # 'pixc': a sample's photometric and body-mask augmentation
    "calibration": 0x6361,      # 'ca': a step's calibration error
}


def entropy(seed: int, stream: str, *counters: int) -> list[int]:
    """The entropy of a draw: ``[seed, *counters, tag of stream]`` (ValueError naming the
    streams for an unknown one)."""
    if stream not in STREAMS:
        raise ValueError(f"unknown random stream {stream!r}; the streams are {sorted(STREAMS)}")
    return [int(seed), *(int(c) for c in counters), STREAMS[stream]]


def host_rng(seed: int, stream: str, *counters: int) -> np.random.Generator:
    """A NumPy generator of the draw ``(seed, stream, counters...)``."""
    return np.random.default_rng(entropy(seed, stream, *counters))


def device_key(seed: int, stream: str, *counters: int) -> jax.Array:
    """A JAX PRNG key of the draw ``(seed, stream, counters...)`` (its 32-bit seed from NumPy's
    SeedSequence of the same entropy as :func:`host_rng`)."""
    state = np.random.SeedSequence(entropy(seed, stream, *counters)).generate_state(1)[0]
    return jax.random.PRNGKey(int(state))
