"""Losses against hand-computed values (candidates 0.5, 1, 2, 4 m: inverses 2, 1, 0.5, 0.25)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gijax.train.losses import smooth_l1_loss, two_hot_target, volume_loss

CAND = jnp.array([0.5, 1.0, 2.0, 4.0], jnp.float32)


def _px(values):
    """A (1, 1, n) label panorama from a list."""
    return jnp.asarray(values, jnp.float32).reshape(1, 1, -1)


def test_two_hot_hand_values():
    # 1.5 m -> 1/1.5 = 0.6667 lies between inverse 1 (index 1) and 0.5 (index 2):
    # weight on index 1 = (0.6667 - 0.5) / (1 - 0.5) = 1/3.
    t = np.asarray(two_hot_target(_px([1.5, 0.4, 1e6, 1.0, 3.0]), CAND))[0, :, 0, :].T
    np.testing.assert_allclose(t[0], [0, 1 / 3, 2 / 3, 0], atol=1e-6)
    np.testing.assert_allclose(t[1], [1, 0, 0, 0], atol=1e-6)          # nearer than 0.5 m: clamped
    np.testing.assert_allclose(t[2], [0, 0, 0, 1], atol=1e-6)          # sky: clamped to 4 m
    np.testing.assert_allclose(t[3], [0, 1, 0, 0], atol=1e-6)          # exactly on a candidate
    # 3 m -> 0.3333 between 0.5 (index 2) and 0.25 (index 3): weight (0.3333-0.25)/0.25 = 1/3
    np.testing.assert_allclose(t[4], [0, 0, 1 / 3, 2 / 3], atol=1e-6)


def test_volume_loss_hand_value_and_mask():
    p = [0.1, 0.2, 0.3, 0.4]
    t = [0.0, 1 / 3, 2 / 3, 0.0]
    expected = -sum(ti * math.log(pi) + (1 - ti) * math.log(1 - pi) for pi, ti in zip(p, t)) / 4
    # Pixel 0 is labelled 1.5 m; pixel 1 is marked invalid, pixel 2 has a NaN label: both ignored.
    prob = jnp.asarray([p, [0.97, 0.01, 0.01, 0.01], [0.25] * 4], jnp.float32).T.reshape(1, 4, 1, 3)
    dist = _px([1.5, 0.7, np.nan])
    valid = jnp.asarray([[[1, 0, 1]]], bool)
    got = float(volume_loss(prob, dist, valid, CAND))
    assert abs(got - expected) < 1e-6, (got, expected)
    # no usable pixel: a finite zero, not NaN
    assert float(volume_loss(prob, dist, jnp.zeros_like(valid), CAND)) == 0.0


def test_smooth_l1_hand_values():
    # err 96 * (0.6 - 1/1.5) = -6.4 -> 6.4 - 0.5 = 5.9 ; err 96 * (0.67 - 1/1.5) = 0.32 ->
    # 0.5 * 0.32^2 = 0.0512 ; third pixel invalid
    inv = _px([0.6, 0.67, 5.0])
    dist = _px([1.5, 1.5, 1.0])
    valid = jnp.asarray([[[True, True, False]]])
    got = float(smooth_l1_loss(inv, dist, valid, CAND))
    expected = (5.9 + 0.5 * (96 * (0.67 - 1 / 1.5)) ** 2) / 2
    assert abs(got - expected) < 2e-4, (got, expected)
    # label beyond 4 m is clamped to 1/4: prediction 0.25 has zero loss
    assert float(smooth_l1_loss(_px([0.25]), _px([50.0]), jnp.ones((1, 1, 1), bool), CAND)) < 1e-9


def test_gradients_finite_at_saturated_probabilities():
    logits = jnp.asarray([[80.0, -80.0, 0.0, -80.0]]).T.reshape(1, 4, 1, 1)

    def f(lg):
        return volume_loss(jax.nn.softmax(lg, axis=1), _px([3.0]), jnp.ones((1, 1, 1), bool), CAND)

    g = jax.grad(f)(logits)           # fully saturated: finite (zero where the log is clamped)
    assert np.all(np.isfinite(np.asarray(g)))
    # moderately confident and wrong: the gradient moves mass from index 0 towards 2 and 3
    g = jax.grad(f)(logits / 10.0)
    assert float(g[0, 0, 0, 0]) > 0 and float(g[0, 2, 0, 0]) < 0 and float(g[0, 3, 0, 0]) < 0
    gi = jax.grad(lambda x: smooth_l1_loss(x, _px([1.5]), jnp.ones((1, 1, 1), bool), CAND))(_px([0.6]))
    np.testing.assert_allclose(np.asarray(gi), [[[-96.0]]], rtol=1e-5)   # slope -1 x scale 96


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(0.05, 1e3), min_size=8, max_size=8))
def test_two_hot_reproduces_clamped_inverse(ds):
    t = np.asarray(two_hot_target(_px(ds), CAND), np.float64)[0, :, 0, :]    # (D, n)
    inv_c = 1.0 / np.asarray(CAND, np.float64)
    np.testing.assert_allclose(t.sum(0), 1.0, atol=1e-6)
    assert (t >= -1e-7).all() and ((t > 1e-7).sum(0) <= 2).all()
    expected = np.clip(1.0 / np.asarray(ds), 0.25, 2.0)
    np.testing.assert_allclose((t * inv_c[:, None]).sum(0), expected, rtol=1e-5, atol=1e-6)
