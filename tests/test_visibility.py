"""Which points a viewpoint sees (`gijax.geometry.visibility`), against ray-square
intersections in closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.geometry.visibility import visible_from

WIDTH = 180                          # 2 degree bins
HALF = 0.3                           # the occluder: a square of side 0.6 m on the plane z = 1
BIN = 2 * np.pi / WIDTH


def _plane(depth, half, step):
    """Points of the square of half side ``half`` on the plane x = ``depth``: the scene looks
    along +x, where the bins are 2 x 2 degrees (not at the grid's pole, +z)."""
    s = np.arange(-half, half + 1e-9, step)
    a, b = np.meshgrid(s, s, indexing="ij")
    return np.stack([np.full(a.shape, depth), a, b], -1).reshape(-1, 3)


def _scene():
    """A dense square occluder on x = 1 in front of a wall on x = 4 (points, metres)."""
    return _plane(1.0, HALF, 0.01), _plane(4.0, 2.5, 0.05)


def _behind_square(wall, centre, half):
    """Whether the segment from ``centre`` to each wall point crosses the square of half side
    ``half`` on x = 1 (closed form)."""
    s = (1.0 - centre[0]) / (wall[:, 0] - centre[0])
    hit = centre[1:] + s[:, None] * (wall[:, 1:] - centre[1:])
    return np.all(np.abs(hit) <= half, -1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_square_hides_the_wall_behind_it_as_seen_from_each_viewpoint(seed):
    """From viewpoints around the origin, the wall points behind the square (closed form) are
    hidden and the others seen, except within a bin or so of the square's silhouette; every
    point of the square itself is seen. The silhouette shifts with the viewpoint: the
    hidden set is the viewpoint's, not the origin's."""
    rng = np.random.default_rng(seed)
    centre = np.concatenate([[rng.uniform(-0.2, 0.2)], rng.uniform(-0.4, 0.4, 2)])
    square, wall = _scene()
    seen = np.asarray(visible_from(jnp.asarray(np.concatenate([square, wall])),
                                   jnp.asarray(centre), WIDTH))
    seen_square, seen_wall = seen[: len(square)], seen[len(square):]
    assert np.all(seen_square == 1.0)
    # One bin diagonal at the square's distance (about 1.2 m from any of these viewpoints).
    slack = 1.5 * BIN * np.sqrt(2.0) * 1.3
    surely_hidden = _behind_square(wall, centre, HALF - slack)
    surely_seen = ~_behind_square(wall, centre, HALF + slack)
    assert surely_hidden.sum() > 50
    assert np.all(seen_wall[surely_hidden] == 0.0)
    assert np.all(seen_wall[surely_seen] == 1.0)
    # Seen from the origin instead, other wall points would be hidden.
    moved = _behind_square(wall, np.zeros(3), HALF + slack) & surely_seen
    if np.linalg.norm(centre[1:]) > 0.2:
        assert moved.sum() > 0


def test_margin_and_empty_bins():
    """Two points in one direction: the farther is hidden unless it lies within the margin of
    the nearer (relative, in inverse distance); a point alone in its bin is always seen; a
    point at the viewpoint itself gives finite output."""
    d = np.array([0.3, -0.2, 0.9])
    d /= np.linalg.norm(d)
    for far, margin, expect in ((2.0, 0.05, 0.0), (1.04, 0.05, 1.0), (1.06, 0.05, 0.0),
                                (1.5, 0.4, 1.0)):
        pts = jnp.asarray(np.stack([d, far * d, [0.0, 0.0, -5.0]]))
        out = np.asarray(visible_from(pts, jnp.zeros(3), 64, margin))
        assert out.tolist() == [1.0, expect, 1.0], (far, margin, out)
    out = visible_from(jnp.asarray(np.stack([np.zeros(3), d])), jnp.zeros(3), 64)
    assert np.all(np.isfinite(np.asarray(out)))


def test_no_derivative_flows_through_the_test():
    pts = jnp.asarray(np.random.default_rng(0).normal(size=(20, 3)))
    grad = jax.grad(lambda p: jnp.sum(visible_from(p, jnp.zeros(3), 16) * p[:, 0]))(pts)
    np.testing.assert_array_equal(np.asarray(grad)[:, 1:], 0.0)
    np.testing.assert_array_equal(np.asarray(grad)[:, 0],
                                  np.asarray(visible_from(pts, jnp.zeros(3), 16)))
