"""The use the package exists for: a stereo loss differentiated through the whole network (raw
fisheye images -> surrogates -> features -> sweep -> cost volume -> U-Net -> regression) with
respect to the camera positions and the candidate list, finite and equal to central finite
differences.

Everything runs in float64 so that a small step (1e-6) stays far from rounding noise; the
network's piecewise-linear parts (bilinear sampling, LeakyReLU) then have a kink inside the
step only with negligible probability, and directional derivatives are compared so one
gradient evaluation and a handful of loss evaluations suffice.
"""


import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from gijax.geometry.layouts import TRAIN_BASELINE, synthetic_camera
from gijax.geometry.rig import make_rig
from gijax.model import create_model, model_grids
from gijax.nn.presets import ModelConfig
from gijax.sweep.grids import fisheye_surrogates, surrogate_resampling
from gijax.train.losses import smooth_l1_loss

# Compiled without XLA's optimisation passes (conftest's quick_compiles): these checks do
# not depend on them, and they dominate this module's time.
pytestmark = pytest.mark.usefixtures("quick_compiles")

TINY = ModelConfig(
    name="tiny-grad", num_candidates=8, candidates="gi", loss="smooth_l1", features="plain",
    cost_volume="variance", feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
    surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64), image_scale=1 / 16)
CANDIDATES = np.array([0.5, 0.6, 0.75, 0.95, 1.3, 1.9, 3.8, 100.0])
STEP = 1e-6


def _positions():
    ang = np.deg2rad([90.0, 210.0, 330.0])
    return np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], -1) * TRAIN_BASELINE / np.sqrt(3)


@pytest.fixture(scope="module")
def problem():
    """A tiny float64 model in eval mode, raw images, masks, a target and the loss as a function
    of (camera positions, candidates)."""
    with jax.enable_x64(True):
        model = create_model(TINY, seed=3)
        model.eval()
        graphdef, state = nnx.split(model)
        state = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64), state)
        size = 64
        cams = [synthetic_camera(size, 300.0 / 16) for _ in range(3)]
        rng = np.random.default_rng(0)
        # Smooth random images: a few low-frequency sinusoids, so that sampling the images at
        # moved coordinates changes the loss smoothly.
        yy, xx = np.mgrid[0:size, 0:size] / size
        images = np.stack([np.stack([
            0.5 + 0.4 * np.sin(2 * np.pi * (rng.uniform(0.5, 2) * xx + rng.uniform(0.5, 2) * yy)
                               + rng.uniform(0, 6)) for _ in range(3)], -1)
            for _ in range(3)])[None]
        masks = np.ones((1, 3, size, size))
        target = np.full((1, *TINY.output_hw), 2.0)
        valid = np.ones((1, *TINY.output_hw), bool)

        def loss(positions, candidates):
            rig = make_rig(cams, jnp.tile(jnp.eye(3, dtype=jnp.float64), (3, 1, 1)), positions,
                           positions[0], dtype=jnp.float64)
            grids = model_grids(TINY, rig, candidates)
            sur, sur_masks = fisheye_surrogates(surrogate_resampling(rig, TINY.surrogate_hw),
                                                jnp.asarray(images), jnp.asarray(masks))
            out = nnx.merge(graphdef, state)(sur, sur_masks, grids)
            return smooth_l1_loss(out["inv_distance"], jnp.asarray(target), jnp.asarray(valid),
                                  candidates)

        yield jax.jit(loss), jax.jit(jax.grad(loss, argnums=(0, 1)))


def test_loss_gradient_wrt_camera_positions_and_candidates_matches_finite_differences(problem):
    loss, grad = problem
    with jax.enable_x64(True):
        pos = jnp.asarray(_positions())
        cand = jnp.asarray(CANDIDATES)
        g_pos, g_cand = grad(pos, cand)
        assert np.all(np.isfinite(g_pos)) and np.all(np.isfinite(g_cand))
        # The loss must actually depend on both: a zero gradient would pass any comparison.
        assert np.abs(g_pos).max() > 1e-6 and np.abs(g_cand).max() > 1e-6
        rng = np.random.default_rng(1)
        for _ in range(3):
            # Directions that keep the list ascending and the rig non-degenerate.
            v_pos = rng.normal(size=pos.shape)
            v_cand = rng.normal(size=cand.shape) * CANDIDATES * 0.1
            plus = loss(pos + STEP * v_pos, cand + STEP * v_cand)
            minus = loss(pos - STEP * v_pos, cand - STEP * v_cand)
            numeric = float(plus - minus) / (2 * STEP)
            analytic = float(np.sum(g_pos * v_pos) + np.sum(g_cand * v_cand))
            assert analytic == pytest.approx(numeric, rel=2e-4, abs=1e-9)


def test_candidate_gradient_alone_matches_finite_differences(problem):
    """Each candidate's own partial derivative (the quantity a learned list follows)."""
    loss, grad = problem
    with jax.enable_x64(True):
        pos = jnp.asarray(_positions())
        cand = jnp.asarray(CANDIDATES)
        _, g_cand = grad(pos, cand)
        for i in (1, 3):
            e = np.zeros_like(CANDIDATES)
            e[i] = CANDIDATES[i] * 1e-6
            numeric = float(loss(pos, cand + e) - loss(pos, cand - e)) / (2 * e[i])
            assert float(g_cand[i]) == pytest.approx(numeric, rel=2e-4, abs=1e-9)
