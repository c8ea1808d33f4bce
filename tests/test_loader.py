"""Batch loader: determinism per (seed, epoch), exact resume, process sharding, augmentation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gijax.data.augment import augment_masks, erase_rectangle
from gijax.data.loader import Loader
from gijax.evaluate.labels import usable_label
from gijax.data.reader import DatasetReader
from gijax.random_streams import host_rng
from gijax.data.writer import write_dataset
from gijax.geometry.panorama import Panorama
from gijax.sweep.surrogate import surrogate_images
from test_data_format import PANO, SIZE, synthetic_sample, tiny_rig

SURROGATE = Panorama.hemisphere(8, 32)
N = 11
CONST = (40, 128, 250)


def _sample(rig, i):
    s = synthetic_sample(rig, i)
    if i == 0:  # a flat colour: its surrogate is that colour wherever the mask is valid
        s["images"][:] = np.array(CONST, np.uint8)
    return s


@pytest.fixture(scope="module")
def reader(tmp_path_factory):
    rig = tiny_rig()
    root = tmp_path_factory.mktemp("loader") / "data"
    write_dataset(root, lambda i: _sample(rig, i), rig, PANO, num_samples=N, trajectory_size=5)
    return DatasetReader(root)


def _take(loader, n):
    return [next(loader) for _ in range(n)]


def _loader(reader, **kw):
    opts = dict(batch_size=2, seed=7, surrogate=SURROGATE, workers=2)
    opts.update(kw)
    return Loader(reader, **opts)


def test_batch_shapes_and_values(reader):
    with _loader(reader, shuffle=False, num_epochs=1) as loader:
        batches = list(loader)
    assert len(batches) == N // 2 == len(loader)
    b = batches[0]
    assert b["surrogates"].shape == (2, 3, 8, 32, 3) and b["surrogates"].dtype == np.float32
    assert b["masks"].shape == (2, 3, 8, 32) and b["masks"].dtype == np.float32
    assert b["distance"].shape == (2, 8, 32) and b["valid"].dtype == np.bool_
    # Resampled masks are fractional at mask edges (the forward thresholds them after the sweep).
    assert 0.0 <= b["masks"].min() and b["masks"].max() <= 1.0
    assert np.mean((b["masks"] > 0) & (b["masks"] < 1)) > 0
    assert 0.0 <= b["surrogates"].min() and b["surrogates"].max() <= 1.0
    # The loader's precomputed grids give what surrogate_images computes from scratch.
    s0 = reader[0]
    ref_i, ref_m = surrogate_images(reader.rig, s0["images"], s0["masks"], SURROGATE)
    np.testing.assert_allclose(b["masks"][0], np.asarray(ref_m), atol=1e-5)
    np.testing.assert_allclose(b["surrogates"][0], np.asarray(ref_i), atol=1e-4)
    # Sample 0 is a flat colour: every valid surrogate pixel has exactly that colour.
    m = b["masks"][0] > 0
    assert m.mean() > 0.3
    np.testing.assert_allclose(b["surrogates"][0][m], np.broadcast_to(np.array(CONST) / 255.0,
                                                                 (int(m.sum()), 3)), atol=1e-6)
    # Labels: exact copies of the stored panoramas; 0 m holes are not valid, sky (1e6) is.
    want = synthetic_sample(reader.rig, 1)["pano_distance"]
    np.testing.assert_array_equal(b["distance"][1], want)
    np.testing.assert_array_equal(b["valid"][1], want > 0)
    assert not b["valid"][1][1, :3].any() and b["valid"][1][0, :4].all()
    assert [int(i) for b in batches for i in b["index"]] == list(range(10))


def test_label_valid():
    d = np.array([np.nan, np.inf, -1.0, 0.0, 0.5, 1e6], np.float32)
    np.testing.assert_array_equal(usable_label(d), [False, False, False, False, True, True])


def test_deterministic_per_seed_and_epoch(reader):
    per_epoch = N // 2
    with _loader(reader) as a, _loader(reader, workers=0) as b, _loader(reader, seed=8) as c:
        xa, xb = _take(a, 2 * per_epoch), _take(b, 2 * per_epoch)
        xc = _take(c, per_epoch)
    for u, v in zip(xa, xb):  # thread timing never changes the stream
        for k in u:
            np.testing.assert_array_equal(u[k], v[k])
    e0 = np.concatenate([x["index"] for x in xa[:per_epoch]])
    e1 = np.concatenate([x["index"] for x in xa[per_epoch:]])
    ec = np.concatenate([x["index"] for x in xc])
    assert len(set(e0)) == len(e0) == 10 and len(set(e1)) == 10  # permutations, one left out
    assert not np.array_equal(e0, e1)  # epochs differ
    assert not np.array_equal(e0, ec)  # seeds differ


def test_loaders_sharing_one_pool_give_their_own_streams_and_leave_it_running(reader):
    """A mixture of datasets loads in one shared pool: each loader's batches are those it gives
    with its own threads, and closing a loader cancels only its loads, not the pool."""
    import concurrent.futures
    import threading

    before = threading.active_count()
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        with _loader(reader, seed=7) as own_a, _loader(reader, seed=8) as own_b:
            ref_a, ref_b = _take(own_a, 3), _take(own_b, 3)
        a, b = _loader(reader, seed=7, pool=pool), _loader(reader, seed=8, pool=pool)
        got_a, got_b = [], []
        for _ in range(3):                 # interleaved, as a mixed stream draws them
            got_a.append(next(a))
            got_b.append(next(b))
        a.close()
        assert pool.submit(lambda: 41 + 1).result() == 42     # still running for the others
        got_b.append(next(b))
        b.close()
        assert threading.active_count() <= before + 2          # no threads of their own
    for u, v in zip(ref_a + ref_b, got_a + got_b[:3]):
        for k in u:
            np.testing.assert_array_equal(u[k], v[k])
    assert got_b[3]["index"].shape == (2,)


def test_resume_mid_epoch_yields_exactly_the_rest(reader):
    with _loader(reader, mask_augmentation=True) as full:
        ref = _take(full, 9)  # crosses the epoch boundary after 5 batches
    with _loader(reader, mask_augmentation=True) as first:
        _take(first, 3)
        state = first.state()
    assert (state["epoch"], state["position"]) == (0, 3)
    with _loader(reader, mask_augmentation=True, state=state) as resumed:
        rest = _take(resumed, 6)
        assert (resumed.state()["epoch"], resumed.state()["position"]) == (1, 4)
    for u, v in zip(ref[3:], rest):
        for k in u:
            np.testing.assert_array_equal(u[k], v[k])
    with pytest.raises(ValueError, match="saved with seed=7, but this loader has seed=1"):
        _loader(reader, seed=1, state=state)


def test_process_sharding_partitions_the_epoch(reader):
    count = 3
    per = N // count  # 3 samples each, 9 of 11 used
    shards = []
    for k in range(count):
        with _loader(reader, batch_size=1, process_index=k, process_count=count, workers=0) as ld:
            assert len(ld) == per
            shards.append([int(i) for i in ld.epoch_indices(0)])
    flat = sum(shards, [])
    assert all(len(s) == per for s in shards)
    assert len(set(flat)) == count * per  # disjoint
    with _loader(reader, batch_size=1, workers=0) as single:
        order = [int(i) for i in single.epoch_indices(0)]
    # Round-robin over the same global order: shard k holds order[k::count] of the first 9.
    for k in range(count):
        assert shards[k] == order[: count * per][k::count]
    with pytest.raises(ValueError, match="process_index must be in"):
        _loader(reader, process_index=3, process_count=3)


@settings(max_examples=40, deadline=None)
@given(st.integers(8, 1200), st.integers(8, 1200), st.integers(0, 2**31 - 1))
def test_erase_rectangle_bounds(h, w, seed):
    if max(h, w) / min(h, w) > 8:  # very elongated images cannot fit every aspect
        h = min(h, 8 * w)
        w = min(w, 8 * h)
    top, left, rh, rw = erase_rectangle(np.random.default_rng(seed), h, w)
    assert 0 <= top and top + rh <= h and 0 <= left and left + rw <= w
    # Rounding each side to whole pixels moves it by at most half a pixel.
    assert (rh - 0.5) * (rw - 0.5) <= 0.20 * h * w + 1e-9
    assert (rh + 0.5) * (rw + 0.5) >= 0.05 * h * w - 1e-9
    assert (rh - 0.5) / (rw + 0.5) <= 3.3 and (rh + 0.5) / (rw - 0.5) >= 0.3


def test_erase_rectangle_distribution():
    """Over many draws the area fraction and aspect fill their whole ranges."""
    rng = np.random.default_rng(0)
    draws = np.array([erase_rectangle(rng, 512, 512)[2:] for _ in range(2000)], float)
    area = draws[:, 0] * draws[:, 1] / 512**2
    aspect = draws[:, 0] / draws[:, 1]
    assert 0.05 - 2e-3 <= area.min() < 0.06 and 0.19 < area.max() <= 0.20 + 2e-3
    assert 0.29 < aspect.min() < 0.36 and 2.8 < aspect.max() < 3.4
    assert abs(np.median(np.log(aspect))) < 0.1  # log-uniform: symmetric around ratio 1


def test_augment_masks_one_camera_rectangle(reader):
    s = reader[3]
    images = s["images"].astype(np.float32) / 255
    masks = s["masks"].astype(np.float32)
    out_i, out_m, (cam, top, left, rh, rw) = augment_masks(images, masks,
                                                          host_rng(7, "erase", 2, 3))
    changed = [c for c in range(3) if not np.array_equal(out_m[c], masks[c])]
    assert changed == [cam] or (changed == [] and masks[cam][top:top + rh,
                                                              left:left + rw].max() == 0)
    expect = masks[cam].copy()
    expect[top:top + rh, left:left + rw] = 0
    np.testing.assert_array_equal(out_m[cam], expect)
    np.testing.assert_array_equal(out_i[cam], images[cam] * expect[..., None])
    for c in set(range(3)) - {cam}:
        np.testing.assert_array_equal(out_i[c], images[c])
    assert 0.05 * SIZE * SIZE * 0.8 <= rh * rw <= 0.2 * SIZE * SIZE * 1.2
    again = augment_masks(images, masks, host_rng(7, "erase", 2, 3))[2]
    other = [augment_masks(images, masks, host_rng(7, "erase", e, 3))[2] for e in range(3, 8)]
    assert again == (cam, top, left, rh, rw)
    assert any(o != again for o in other)
    np.testing.assert_array_equal(masks, s["masks"])  # inputs untouched


def test_loader_mask_augmentation_removes_valid_pixels(reader):
    with _loader(reader, shuffle=False, num_epochs=1) as plain, \
            _loader(reader, shuffle=False, num_epochs=1, mask_augmentation=True) as aug:
        p, a = _take(plain, 2), _take(aug, 2)
    for u, v in zip(p, a):
        assert np.all(v["masks"] <= u["masks"])
        lost = (u["masks"] - v["masks"]).sum(axis=(2, 3))  # (B, Ncam)
        assert np.all((lost > 0).sum(axis=1) <= 1)  # at most one camera per sample
        assert (lost > 0).sum() >= 1
        np.testing.assert_array_equal(u["distance"], v["distance"])


def test_dataset_smaller_than_batch_is_an_error(reader):
    with pytest.raises(ValueError, match="fewer than batch_size 64"):
        _loader(reader, batch_size=64)
