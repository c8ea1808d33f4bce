"""The assembled network: camera-count and order invariance, jit = eager, gradients, candidates
swapped at inference, and input validation (small custom configs; paper shapes in benchmarks)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from gijax.geometry.layouts import TRAIN_BASELINE, synthetic_camera
from gijax.geometry.rig import make_rig
from gijax.model import OmniStereoNet, create_model, model_grids, with_conv3d
from gijax.nn.presets import ModelConfig
from gijax.train.losses import volume_loss

TINY_VAR = ModelConfig(
    name="tiny-variance", num_candidates=8, candidates="gi", loss="volume", features="spherical",
    cost_volume="variance", feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
    surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64), image_scale=1 / 16)
TINY_CAT = dataclasses.replace(TINY_VAR, name="tiny-concat", loss="smooth_l1", features="plain",
                               cost_volume="concat", unet_in=12)
G8 = np.array([0.5, 0.60103325, 0.73863074, 0.94007016, 1.26849604, 1.91086214, 3.77357055,
               100.0], np.float32)


def tri_positions():
    ang = np.deg2rad([90.0, 210.0, 330.0])
    return np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], -1) * TRAIN_BASELINE / np.sqrt(3)


def tri_rig():
    """The 3-camera training layout, reference point at camera 0."""
    pos = tri_positions()
    return rig_from(pos, pos[0])


def rig_from(positions, reference):
    cams = [synthetic_camera(64, 300.0 / 16) for _ in positions]
    return make_rig(cams, np.tile(np.eye(3), (len(positions), 1, 1)), positions, reference)


def permuted(rig, perm):
    return rig.replace(cameras=tuple(rig.cameras[i] for i in perm),
                       rotations=rig.rotations[jnp.asarray(perm)],
                       translations=rig.translations[jnp.asarray(perm)],
                       masks=tuple(rig.masks[i] for i in perm),
                       names=tuple(rig.names[i] for i in perm))


def inputs(n, seed, batch=1, hw=(32, 128)):
    """Random surrogates and masks with a few rectangular occlusions (like a rig's body)."""
    rng = np.random.default_rng(seed)
    sur = rng.uniform(size=(batch, n, *hw, 3)).astype(np.float32)
    masks = np.ones((batch, n, *hw), np.float32)
    for b in range(batch):
        for i in range(n):
            r, c = rng.integers(hw[0] // 2, hw[0]), rng.integers(0, hw[1] - 16)
            masks[b, i, r:, c:c + rng.integers(4, 16)] = 0.0
    return jnp.asarray(sur), jnp.asarray(masks)


def run(model, sur, masks, rig, cand):
    """The network on surrogates with the sweep grids of ``rig`` and ``cand``."""
    return model(sur, masks, model_grids(model.config, rig, cand))


forward = nnx.jit(run)


pytestmark = pytest.mark.usefixtures("quick_compiles")


@pytest.fixture(scope="module")
def variance_model():
    model = create_model(TINY_VAR, seed=1)
    model.eval()
    return model


def test_variance_model_any_camera_count_and_order(variance_model):
    pos = tri_positions()
    rig3 = rig_from(pos, pos[0])
    sur3, m3 = inputs(3, 0)
    out3 = forward(variance_model, sur3, m3, rig3, jnp.asarray(G8))
    # A fourth camera whose mask is all invalid changes nothing ...
    pos4 = np.concatenate([pos, [[0.25, 0.2, 0.0]]])
    rig4 = rig_from(pos4, pos[0])
    extra, _ = inputs(1, 5)
    sur4 = jnp.concatenate([sur3, extra], axis=1)
    m4_off = jnp.concatenate([m3, jnp.zeros_like(m3[:, :1])], axis=1)
    out4_off = forward(variance_model, sur4, m4_off, rig4, jnp.asarray(G8))
    for key in ("inv_distance", "prob", "entropy", "valid"):
        np.testing.assert_allclose(np.asarray(out4_off[key]), np.asarray(out3[key]), atol=1e-6,
                                   err_msg=key)
    # ... and with its mask on, the same weights use it.
    m4_on = jnp.concatenate([m3, jnp.ones_like(m3[:, :1])], axis=1)
    out4 = forward(variance_model, sur4, m4_on, rig4, jnp.asarray(G8))
    change = np.abs(np.asarray(out4["inv_distance"]) - np.asarray(out3["inv_distance"]))
    # Ten times the equality tolerance above (an untrained tiny net responds weakly).
    assert np.all(np.isfinite(change)) and change.max() > 1e-5
    # Camera order does not matter.
    perm = [2, 0, 1]
    out_p = forward(variance_model, sur3[:, perm], m3[:, perm], permuted(rig3, perm),
                    jnp.asarray(G8))
    np.testing.assert_allclose(np.asarray(out_p["inv_distance"]),
                               np.asarray(out3["inv_distance"]), rtol=1e-5, atol=1e-6)
    # Inverse distance is a convex combination of the candidates' inverses.
    inv = np.asarray(out3["inv_distance"])
    assert np.all(inv >= 1 / G8[-1] - 1e-6) and np.all(inv <= 1 / G8[0] + 1e-6)
    np.testing.assert_allclose(np.asarray(out3["prob"]).sum(1), 1.0, atol=1e-5)


def test_output_stride_1_runs_the_same_weights_with_the_cost_volume_at_the_output_size(
        variance_model):
    """``output_stride=1`` (the G16VV-cpu-fine design): the coarse model's weights load as they
    are; the U-Net's logits come out at the output's size and the probabilities are their
    softmax (no upsampling), and a cell is valid where the coarse model's 2 x 2 block is,
    up to the cells along the coarse grid's edges of visibility."""
    fine_cfg = dataclasses.replace(TINY_VAR, name="tiny-fine", cost_hw=TINY_VAR.output_hw,
                                   output_stride=1)
    fine = create_model(fine_cfg, seed=9)
    nnx.update(fine, nnx.state(variance_model))
    fine.eval()
    rig = tri_rig()
    sur, m = inputs(3, 0)
    out = forward(fine, sur, m, rig, jnp.asarray(G8))
    coarse = forward(variance_model, sur, m, rig, jnp.asarray(G8))
    assert out["logits"].shape == (1, 8, *fine_cfg.output_hw)
    assert out["inv_distance"].shape == coarse["inv_distance"].shape == (1, 16, 64)
    logits = np.asarray(out["logits"], np.float64)
    e = np.exp(logits - logits.max(axis=1, keepdims=True))
    np.testing.assert_allclose(np.asarray(out["prob"]), e / e.sum(1, keepdims=True), atol=1e-6)
    grids = model_grids(fine_cfg, rig, jnp.asarray(G8))
    px, ok = grids.sweep_px, grids.sweep_ok
    assert px.shape == (3, 8, 16, 64, 2) and ok.shape == (3, 8, 16, 64)
    agree = np.mean(np.asarray(out["valid"]) == np.asarray(coarse["valid"]))
    assert agree > 0.9, agree
    assert np.asarray(out["valid"]).any() and np.all(np.isfinite(np.asarray(out["inv_distance"])))


def test_model_grids_are_the_sweep_at_the_configs_sizes():
    """``model_grids``: the sweep of the cost panorama (half the output, 8 x 32) into the
    feature maps (a quarter of the 32 x 128 surrogates), the guide grids (the 16 x 64 output
    into the surrogates) only with the refinement; the other coverage keeps the resolution."""
    from gijax.geometry.panorama import Panorama
    from gijax.model import model_panorama
    from gijax.sweep.grid import sweep_grid
    from gijax.sweep.grids import sweep_grids

    rig = tri_rig()
    cand = jnp.asarray(G8)
    grids = model_grids(TINY_VAR, rig, cand)
    px, ok = sweep_grid(rig, cand, Panorama.hemisphere(8, 32), Panorama.hemisphere(8, 32))
    np.testing.assert_array_equal(np.asarray(grids.sweep_px), np.asarray(px))
    np.testing.assert_array_equal(np.asarray(grids.sweep_ok), np.asarray(ok))
    np.testing.assert_array_equal(np.asarray(grids.candidates), G8)
    assert grids.guide_px is None and grids.guide_ok is None
    refine = model_grids(dataclasses.replace(TINY_VAR, refine=True), rig, cand)
    gpx, gok = sweep_grid(rig, cand, Panorama.hemisphere(16, 64), Panorama.hemisphere(32, 128))
    assert refine.guide_px.shape == (3, 8, 16, 64, 2)
    np.testing.assert_array_equal(np.asarray(refine.guide_px), np.asarray(gpx))
    np.testing.assert_array_equal(np.asarray(refine.guide_ok), np.asarray(gok))
    sphere = model_grids(TINY_VAR, rig, cand, model_panorama(TINY_VAR, "sphere"))
    assert sphere.sweep_px.shape == (3, 8, 16, 32, 2)
    with pytest.raises(ValueError, match="divisible by 16"):
        model_grids(TINY_VAR, rig, cand, Panorama.hemisphere(12, 64))
    with pytest.raises(ValueError, match="needs 8 candidates"):
        model_grids(TINY_VAR, rig, cand[:4])
    with pytest.raises(ValueError, match="both the output panorama and the surrogate size"):
        sweep_grids(rig, cand, Panorama.hemisphere(8, 32), (8, 32), Panorama.hemisphere(16, 64))


def test_fisheye_surrogates_equal_each_cameras_surrogate_image():
    """A batch of raw fisheye images through the surrogate maps gives, per sample, what
    ``surrogate_images`` computes camera by camera from the rig."""
    from gijax.geometry.panorama import Panorama
    from gijax.sweep.grids import fisheye_surrogates, surrogate_resampling
    from gijax.sweep.surrogate import surrogate_images

    rig = tri_rig()
    rng = np.random.default_rng(6)
    images = jnp.asarray(rng.uniform(size=(2, 3, 64, 64, 3)), jnp.float32)
    # Every camera blind on a third of its image (a rig body), another third per sample.
    masks = np.ones((2, 3, 64, 64), np.float32)
    masks[0, :, :, :21] = 0.0
    masks[1, :, 40:] = 0.0
    masks = jnp.asarray(masks)
    sur, sur_masks = fisheye_surrogates(surrogate_resampling(rig, (32, 128)), images, masks)
    assert sur.shape == (2, 3, 32, 128, 3) and sur_masks.shape == (2, 3, 32, 128)
    for b in range(2):
        want, want_masks = surrogate_images(rig, images[b], masks[b], Panorama.hemisphere(32, 128))
        np.testing.assert_allclose(np.asarray(sur[b]), np.asarray(want), atol=1e-4)
        np.testing.assert_allclose(np.asarray(sur_masks[b]), np.asarray(want_masks), atol=1e-4)
        assert 0.3 < float(jnp.mean(sur_masks[b] > 0)) < 0.9


def test_candidates_swap_without_touching_weights(variance_model):
    rig = tri_rig()
    sur, m = inputs(3, 1)
    ev = (1.0 / np.linspace(2.0, 0.01, 8)).astype(np.float32)
    before = jax.tree_util.tree_map(np.asarray, nnx.state(variance_model, nnx.Param))
    out_gi = forward(variance_model, sur, m, rig, jnp.asarray(G8))
    out_ev = forward(variance_model, sur, m, rig, jnp.asarray(ev))
    inv = np.asarray(out_ev["inv_distance"])
    assert np.all(inv >= 0.01 - 1e-6) and np.all(inv <= 2.0 + 1e-6)
    assert np.abs(inv - np.asarray(out_gi["inv_distance"])).max() > 1e-3
    after = jax.tree_util.tree_map(np.asarray, nnx.state(variance_model, nnx.Param))
    jax.tree_util.tree_map(np.testing.assert_array_equal, before, after)


def test_jit_equals_eager(variance_model):
    rig = tri_rig()
    sur, _ = inputs(3, 0)
    # Unmasked: a camera counts where its sampled mask is > 0, so at a mask edge a sweep point
    # on a pixel centre flips with the last bit of its coordinate; that is not what is compared.
    m = jnp.ones(sur.shape[:4], jnp.float32)
    eager = run(variance_model, sur, m, rig, jnp.asarray(G8))
    # Compiled as in use (the module's quick compiles skip XLA's optimisation passes, whose
    # absence changes this untrained net's tiny logits by more than float rounding).
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        jitted = nnx.jit(run)(variance_model, sur, m, rig, jnp.asarray(G8))
    finally:
        jax.config.update("jax_disable_most_optimizations", previous)
    for key in ("inv_distance", "prob", "entropy"):
        np.testing.assert_allclose(np.asarray(jitted[key]), np.asarray(eager[key]), rtol=2e-5,
                                   atol=2e-6, err_msg=key)
    # Validity thresholds (hemisphere edge) could flip on float rounding only.
    assert np.mean(np.asarray(jitted["valid"]) != np.asarray(eager["valid"])) < 2e-3


def test_concat_model_needs_every_camera():
    model = create_model(TINY_CAT, seed=2)
    model.eval()
    rig = tri_rig()
    sur, m = inputs(3, 2)
    full = forward(model, sur, jnp.ones_like(m), rig, jnp.asarray(G8))
    assert np.asarray(full["valid"]).mean() > 0.9
    # Occluding part of one camera's view removes cells from `valid`; the estimate is finite.
    m_half = jnp.ones_like(m).at[:, 1, :, :64].set(0.0)
    part = forward(model, sur, m_half, rig, jnp.asarray(G8))
    assert np.asarray(part["valid"]).mean() < np.asarray(full["valid"]).mean() - 0.1
    assert np.all(np.isfinite(np.asarray(part["distance"])))


def test_every_parameter_gets_a_finite_nonzero_gradient():
    model = create_model(TINY_VAR, seed=3)
    model.train()
    rig = tri_rig()
    sur, m = inputs(3, 3, batch=2)
    rng = np.random.default_rng(4)
    target = jnp.asarray(rng.uniform(0.6, 20.0, size=(2, 16, 64)).astype(np.float32))
    label_ok = jnp.ones((2, 16, 64), bool)
    cand = jnp.asarray(G8)

    @nnx.jit
    def grads(model):
        def loss_fn(model):
            out = run(model, sur, m, rig, cand)
            return volume_loss(out["prob"], target, label_ok, cand)
        return nnx.grad(loss_fn)(model)

    g = grads(model)
    flat = jax.tree_util.tree_flatten_with_path(g)[0]
    assert len(flat) > 20
    scale = max(float(jnp.max(jnp.abs(v))) for _, v in flat)
    for path, v in flat:
        name = jax.tree_util.keystr(path)
        v = np.asarray(v)
        assert np.all(np.isfinite(v)), name
        if "head" in name and "bias" in name:
            # The head's bias shifts all candidates' logits equally; the softmax cancels it.
            assert np.abs(v).max() < 1e-5 * scale, name
        else:
            assert np.abs(v).max() > 1e-9 * scale and np.abs(v).max() > 0, name


def test_create_model_draws_flax_initial_distributions():
    model = create_model(TINY_VAR, seed=7)
    got = jax.tree_util.tree_flatten_with_path(nnx.state(model))[0]
    assert len(got) > 50
    # Flax's defaults: LeCun-normal kernels (variance 1 / fan_in, truncated at 2 sigma),
    # zero biases, shifts and running means, unit scales and running variances.
    z = []
    for path, v in got:
        name = jax.tree_util.keystr(path)
        v = np.asarray(v)
        if "kernel" in name:
            z.append((v * np.sqrt(np.prod(v.shape[:-1]))).ravel())
        elif "scale" in name or "var" in name:
            assert np.all(v == 1.0), name
        else:
            assert np.all(v == 0.0), name
    z = np.concatenate(z)
    assert z.size > 5000 and abs(z.std() - 1.0) < 0.03 and abs(z.mean()) < 0.03
    assert np.abs(z).max() <= 2.0 / 0.87962566103423978 + 1e-5
    other = create_model(TINY_VAR, seed=8)
    assert not np.allclose(np.asarray(other.unet.head.kernel[...]),
                           np.asarray(model.unet.head.kernel[...]))


def test_with_conv3d_copies_the_model_with_another_lowering(variance_model):
    native = with_conv3d(variance_model, "native")
    assert native.config == dataclasses.replace(TINY_VAR, conv3d="native")
    assert variance_model.config.conv3d == "auto"
    # The graph of a model built natively; the same variables, train/eval mode kept.
    fresh = OmniStereoNet(native.config, nnx.Rngs(0))
    fresh.eval()
    assert nnx.graphdef(native) == nnx.graphdef(fresh)
    assert nnx.graphdef(native) != nnx.graphdef(variance_model)
    for a, b in zip(jax.tree_util.tree_leaves(nnx.state(native)),
                    jax.tree_util.tree_leaves(nnx.state(variance_model))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    rig = tri_rig()
    sur, m = inputs(3, 0)
    split = forward(variance_model, sur, m, rig, jnp.asarray(G8))   # 'auto': split on a CPU
    out = forward(native, sur, m, rig, jnp.asarray(G8))
    np.testing.assert_allclose(np.asarray(out["inv_distance"]),
                               np.asarray(split["inv_distance"]), rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="conv3d"):
        with_conv3d(variance_model, "fast")


def test_bad_inputs_raise_before_computing(variance_model):
    pos = tri_positions()
    rig = rig_from(pos, pos[0])
    sur, m = inputs(3, 0)
    cand = jnp.asarray(G8)
    cases = [
        ((sur[:, :2], m[:, :2], rig, cand), "3 cameras but 2"),
        ((sur[..., :2], m, rig, cand), r"\(batch, cameras, 32, 128, 3\)"),
        ((sur[:, :, :16], m, rig, cand), r"\(batch, cameras, 32, 128, 3\)"),
        ((sur, m[:, :2], rig, cand), "masks must have shape"),
        ((sur, m[:, :, 0], rig, cand), "masks must have shape"),
        ((sur, m, rig, cand[:7]), "needs 8 candidates"),
        ((sur, m, rig, cand[::-1]), "ascending"),
        ((sur, m, rig, cand.at[0].set(0.0)), "positive|> 0"),
        ((sur, m, rig, cand.at[3].set(jnp.nan)), "finite"),
    ]
    for args, msg in cases:
        with pytest.raises(ValueError, match=msg):
            run(variance_model, *args)
    concat = create_model(TINY_CAT)
    pos4 = np.concatenate([pos, [[0.25, 0.2, 0.0]]])
    sur4, m4 = inputs(4, 0)
    with pytest.raises(ValueError, match="concatenates exactly 3 cameras"):
        run(concat, sur4, m4, rig_from(pos4, pos[0]), cand)
    with pytest.raises(ValueError, match="unknown model preset"):
        create_model("G17")
    with pytest.raises(ValueError, match="preset name or a ModelConfig"):
        create_model(42)


def test_colour_guide_matches_a_loop_over_cameras_and_candidates():
    """The refinement's guide against a plain loop: per candidate, the mean and spread of the
    colours of the cameras that see the point and the share that see it, weighted by the
    candidate probabilities."""
    from gijax.nn.refine import colour_guide

    rng = np.random.default_rng(4)
    b, n, d, h, w = 2, 3, 4, 2, 5
    colour = rng.uniform(size=(b, n, d, h, w, 3))
    seen = (rng.uniform(size=(b, n, d, h, w)) > 0.3).astype(np.float64)
    prob = rng.dirichlet(np.ones(d), size=(b, h, w)).transpose(0, 3, 1, 2)
    got = np.asarray(colour_guide(jnp.asarray(colour), jnp.asarray(seen), jnp.asarray(prob)))
    want = np.zeros((b, h, w, 5))
    for bi, k, i, j in np.ndindex(b, d, h, w):
        cams = [c for c in range(n) if seen[bi, c, k, i, j]]
        cols = colour[bi, cams, k, i, j] if cams else np.zeros((0, 3))
        mean = cols.mean(0) if cams else np.zeros(3)
        spread = np.sqrt(cols.var(0).mean()) if cams else 0.0
        want[bi, i, j] += prob[bi, k, i, j] * np.r_[mean, spread, len(cams) / n]
    np.testing.assert_allclose(got, want, atol=2e-6)


def test_guided_refinement_starts_as_the_identity_and_trains_only_itself():
    """``refine=True``: zero-initialised, the refined inverse distance is the soft-argmax one;
    with a non-zero head it moves, inside the candidates' range; the refinement's loss
    (smooth L1 on its output, added to the volume loss) sends gradients to the refinement's
    weights only, not to the cost volume or U-Net (their inputs to it are constants)."""
    from gijax.train.losses import model_loss, smooth_l1_loss

    cfg = dataclasses.replace(TINY_VAR, name="tiny-refine", refine=True)
    model = create_model(cfg, seed=2)
    model.eval()
    rig = tri_rig()
    sur, m = inputs(3, 2)
    cand = jnp.asarray(G8)
    out = forward(model, sur, m, rig, cand)
    np.testing.assert_array_equal(np.asarray(out["inv_distance"]),
                                  np.asarray(out["inv_distance_coarse"]))
    model.refine.head.kernel[...] = 2e-3 * jnp.ones_like(model.refine.head.kernel[...])
    moved = forward(model, sur, m, rig, cand)
    inv = np.asarray(moved["inv_distance"])
    assert np.abs(inv - np.asarray(moved["inv_distance_coarse"])).max() > 1e-3
    assert inv.min() >= 1 / G8[-1] - 1e-7 and inv.max() <= 1 / G8[0] + 1e-7
    np.testing.assert_allclose(np.asarray(moved["distance"]), 1 / inv, rtol=1e-6)

    distance = jnp.full((1, *cfg.output_hw), 2.0)
    valid = jnp.ones((1, *cfg.output_hw), bool)
    volume_only = {k: v for k, v in moved.items() if k != "inv_distance_coarse"}
    assert float(model_loss("volume", moved, distance, valid, cand)) == pytest.approx(
        float(model_loss("volume", volume_only, distance, valid, cand))
        + float(smooth_l1_loss(moved["inv_distance"], distance, valid, cand)), rel=1e-6)

    graphdef, params, rest = nnx.split(model, nnx.Param, ...)

    def refine_loss(p):
        o = run(nnx.merge(graphdef, p, rest), sur, m, rig, cand)
        return smooth_l1_loss(o["inv_distance"], distance, valid, cand)

    grads = nnx.to_pure_dict(jax.jit(jax.grad(refine_loss))(params))
    flat = {"/".join(map(str, k)): np.asarray(v)
            for k, v in __import__("flax").traverse_util.flatten_dict(grads).items()}
    assert all(np.all(np.isfinite(g)) for g in flat.values())
    assert any(np.abs(g).max() > 0 for k, g in flat.items() if k.startswith("refine/"))
    assert all(np.abs(g).max() == 0 for k, g in flat.items() if not k.startswith("refine/"))


def test_matching_skip_starts_as_the_identity_and_adds_the_convolved_cost():
    """``matching_skip=True``: with the zero kernel it starts from, the network's outputs are
    those of the same weights without it (bit for bit); with a kernel set, the logits move by
    ``SKIP_GAIN`` times the 3x3x3 correlation of the matching cost with it (zero padding),
    checked against a numpy sum over the 27 taps; at the zero start the volume loss's gradient
    reaches the kernel (finite, non-zero). A model without a matching cost cannot have one."""
    from gijax.nn.matching_skip import SKIP_GAIN

    base_cfg = dataclasses.replace(TINY_VAR, name="tiny-zncc", matching_cost="zncc")
    cfg = dataclasses.replace(base_cfg, name="tiny-skip", matching_skip=True)
    base = create_model(base_cfg, seed=2)
    model = create_model(cfg, seed=9)
    nnx.update(model, nnx.state(base))
    for m in (base, model):
        m.eval()
    rig = tri_rig()
    sur, m = inputs(3, 2)
    cand = jnp.asarray(G8)
    want = forward(base, sur, m, rig, cand)
    got = forward(model, sur, m, rig, cand)
    for key in ("logits", "inv_distance", "prob"):
        np.testing.assert_array_equal(np.asarray(got[key]), np.asarray(want[key]))

    kernel = np.random.default_rng(3).normal(size=(3, 3, 3, 1, 1)).astype(np.float32)
    model.matching_skip.conv.kernel[...] = jnp.asarray(kernel)
    moved = forward(model, sur, m, rig, cand)
    cost = np.asarray(nnx.jit(lambda mod: mod.matching(sur, m, model_grids(cfg, rig, cand)))(
        model))[..., 0]                                              # (B, D, h, w)
    padded = np.pad(cost, ((0, 0), (1, 1), (1, 1), (1, 1)))
    d, h, w = cost.shape[1:]
    expect = sum(kernel[i, j, k, 0, 0] * padded[:, i:i + d, j:j + h, k:k + w]
                 for i in range(3) for j in range(3) for k in range(3))
    np.testing.assert_allclose(np.asarray(moved["logits"]) - np.asarray(want["logits"]),
                               SKIP_GAIN * expect, rtol=1e-4, atol=1e-4)
    assert np.abs(expect).max() > 0.1

    model.matching_skip.conv.kernel[...] = jnp.zeros((3, 3, 3, 1, 1))
    target = jnp.full((1, *cfg.output_hw), 2.0)
    label_ok = jnp.ones((1, *cfg.output_hw), bool)
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)

    def loss(p):
        out = run(nnx.merge(graphdef, p, rest), sur, m, rig, cand)
        return volume_loss(out["prob"], target, label_ok, cand)

    grad = np.asarray(jax.jit(jax.grad(loss))(params)["matching_skip"]["conv"]["kernel"][...])
    assert np.all(np.isfinite(grad)) and np.abs(grad).max() > 1e-6
    with pytest.raises(ValueError, match="matching_skip"):
        dataclasses.replace(TINY_VAR, matching_skip=True)


def test_every_stage_names_its_operations_forward_and_backward():
    # The step profile (benchmarks/bench_step_profile.py) attributes XLA instructions to the
    # network's stages by these scopes: each stage's operations, and their transposes in the
    # gradient, must carry its name (lowered only, nothing compiled).
    from gijax.model import STAGES

    cfg = dataclasses.replace(TINY_VAR, name="tiny-all-stages", refine=True,
                              matching_cost="zncc", matching_skip=True)
    model = create_model(cfg, seed=0)
    rig = tri_rig()
    sur, masks = inputs(3, 0)
    grids = model_grids(cfg, rig, jnp.asarray(G8))
    graphdef, state = nnx.split(model)

    def loss(state):
        out = nnx.merge(graphdef, state)(sur, masks, grids)
        # The refinement holds the coarse estimate constant: both outputs reach every weight.
        return jnp.mean(out["inv_distance"]) + jnp.mean(out["inv_distance_coarse"])

    text = jax.jit(jax.grad(loss)).lower(state).as_text(debug_info=True)
    for stage in STAGES:
        assert f"jvp({stage})" in text, stage
    # The matching cost is computed from the images alone: it has no backward.
    for stage in ("extract_features", "sweep", "build_cost_volume", "unet_logits", "regress",
                  "refined"):
        assert f"transpose(jvp({stage}))" in text, stage
