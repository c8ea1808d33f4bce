"""The named random streams: one entropy layout, streams apart, draws that are pure functions of
(seed, stream, counters), and the layout the data pipeline's recorded runs were drawn with."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from gijax.data.loader import epoch_order
from gijax.random_streams import STREAMS, device_key, entropy, host_rng


def _draws(rng: np.random.Generator) -> list:
    return rng.integers(0, 2**31, 4).tolist()


def test_every_stream_seed_and_counter_gives_its_own_draws():
    cases = [(s, name, c) for s in (0, 1) for name in STREAMS for c in ((0, 0), (0, 1), (1, 0))]
    host = {tuple(_draws(host_rng(s, name, *c))) for s, name, c in cases}
    keys = {tuple(np.asarray(jax.random.key_data(device_key(s, name, *c))).tolist())
            for s, name, c in cases}
    assert len(host) == len(cases) and len(keys) == len(cases)
    assert len(set(STREAMS.values())) == len(STREAMS)
    # The same draw again is the same numbers (a resumed run draws what it drew).
    assert _draws(host_rng(3, "mixture", 7)) == _draws(host_rng(3, "mixture", 7))
    np.testing.assert_array_equal(jax.random.key_data(device_key(3, "pixels", 2, 1)),
                                  jax.random.key_data(device_key(3, "pixels", 2, 1)))


def test_the_entropy_layout_is_seed_counters_tag():
    # The layout the shuffling, mask erasing and pixel augmentation have drawn with since the
    # first recorded runs: NumPy's generator of [seed, counters..., tag].
    assert entropy(5, "shuffle", 2) == [5, 2, 0x73687566]
    np.testing.assert_array_equal(epoch_order(12, 5, 2),
                                  np.random.default_rng([5, 2, 0x73687566]).permutation(12))
    assert entropy(7, "erase", 2, 3) == [7, 2, 3, 0x6D61736B]
    state = np.random.SeedSequence([3, 2, 1, 0x70697863]).generate_state(1)[0]
    np.testing.assert_array_equal(jax.random.key_data(device_key(3, "pixels", 2, 1)),
                                  jax.random.key_data(jax.random.PRNGKey(int(state))))


def test_an_unknown_stream_is_named_with_the_choices():
    with pytest.raises(ValueError, match=r"unknown random stream 'shufle'; the streams are "
                                         r"\['calibration', 'erase', 'mixture'"):
        host_rng(0, "shufle", 1)
