"""Rig plots: fields of view from masks, views in the rig's up frame, labels that can be read."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gijax.geometry.cameras import make_camera
from gijax.geometry.field_of_view import mask_field_of_view
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.panorama_frame import choose_panorama, with_panorama_rotation
from gijax.geometry.rig import make_rig
from gijax.viz.rig_plot import camera_fields_of_view, plot_rig, rig_figure, view_axes

SIZE = 41
FOCAL = 9.0


def _equidistant(fov_deg=None, focal=FOCAL):
    c = (SIZE - 1) / 2.0
    return make_camera("equidistant", dict(fx=focal, fy=focal, cx=c, cy=c), SIZE, SIZE, fov_deg)


def _disc(radius):
    rows, cols = np.mgrid[:SIZE, :SIZE]
    c = (SIZE - 1) / 2.0
    return (np.hypot(cols - c, rows - c) <= radius).astype(np.uint8)


@pytest.mark.parametrize("radius", [6.0, 12.5, 19.0])
def test_mask_field_of_view_is_the_widest_valid_pixel_of_an_equidistant_lens(radius):
    # r = f theta: the widest valid pixel centre of a disc mask sees r_max / f off the axis.
    mask = _disc(radius)
    rows, cols = np.nonzero(mask)
    c = (SIZE - 1) / 2.0
    r_max = np.hypot(cols - c, rows - c).max()
    got = float(mask_field_of_view(_equidistant(), mask))
    assert got == pytest.approx(2.0 * r_max / FOCAL, rel=1e-5)


def test_mask_field_of_view_is_bounded_by_the_set_cone_and_zero_for_an_empty_mask():
    full = np.ones((SIZE, SIZE), np.uint8)
    assert float(mask_field_of_view(_equidistant(120.0), full)) == pytest.approx(
        math.radians(120.0), rel=1e-6)
    assert float(mask_field_of_view(_equidistant(), np.zeros((SIZE, SIZE)))) == 0.0


def _outward_ring(n=4, radius=0.05):
    """Cameras on a ring in the rig's x-z plane, looking outward; up is rig -y (image up)."""
    angles = 2 * np.pi * np.arange(n) / n
    rots, pos = [], []
    for a in angles:
        forward = np.array([math.sin(a), 0.0, math.cos(a)])
        down = np.array([0.0, 1.0, 0.0])
        rots.append(np.stack([np.cross(down, forward), down, forward], axis=1))
        pos.append(radius * forward)
    rig = make_rig([_equidistant()] * n, np.stack(rots), np.stack(pos), np.zeros(3),
                   masks=[_disc(15.0)] * n, dtype=np.float32)
    return with_panorama_rotation(rig, choose_panorama(rig).rotation)


def test_views_use_the_rigs_up_axis():
    rig = _outward_ring()
    axes = view_axes(rig)
    np.testing.assert_allclose(axes[:, 2], [0.0, -1.0, 0.0], atol=1e-9)
    view = np.asarray(rig.translations) @ axes
    # Seen from above, an outward ring is a circle of its radius at height 0.
    np.testing.assert_allclose(np.hypot(view[:, 0], view[:, 1]), 0.05, atol=1e-9)
    np.testing.assert_allclose(view[:, 2], 0.0, atol=1e-9)


def test_fields_of_view_say_where_they_come_from():
    ring = camera_fields_of_view(_outward_ring())
    assert {source for _, source in ring} == {"mask"}
    no_mask = make_rig([_equidistant(190.0), _equidistant(focal=14.0)], np.tile(np.eye(3), (2, 1, 1)),
                       [[0.0, 0, 0], [0.1, 0, 0]], dtype=np.float32)
    (cone, s0), (lens, s1) = camera_fields_of_view(no_mask)
    assert (s0, s1) == ("cone", "lens")
    assert cone == pytest.approx(math.radians(190.0), rel=1e-6)
    # The image's corner, 20.5 * sqrt(2) px off the axis (sides at -0.5 and SIZE - 0.5), is
    # the widest the whole image sees.
    assert lens == pytest.approx(2 * 20.5 * math.sqrt(2) / 14.0, rel=1e-5)


def _overlaps(boxes):
    return [(i, j) for i in range(len(boxes)) for j in range(i + 1, len(boxes))
            if boxes[i].overlaps(boxes[j])]


@pytest.mark.parametrize("make", [_outward_ring, lambda: builtin_rig("paper-train")])
def test_figure_labels_do_not_overlap_and_axes_agree_with_titles(make):
    import matplotlib.pyplot as plt

    rig = make()
    fig = rig_figure(rig, "rig")
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        top, side = fig.axes[:2]
        up = view_axes(rig)[:, 2]
        for ax in (top, side):
            assert not ax.xaxis_inverted() and not ax.yaxis_inverted()
            names = [t for t in ax.texts if t.get_text()]
            boxes = [t.get_window_extent(renderer) for t in names]
            assert not _overlaps(boxes), [t.get_text() for t in names]
            # Every camera is named once per view, alone or with the cameras at its spot.
            labelled = sorted(n for t in names for n in t.get_text().split(", "))
            assert labelled == sorted(rig.names)
        assert "out of the page" in top.get_title() and "vertical" in side.get_title()
        assert f"{up[2] + 0.0:+.2f}]" in top.get_title()
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        assert all("fov" in legend[i] for i in range(rig.num_cameras))
        fig_box = fig.bbox
        legend_box = fig.legends[0].get_window_extent(renderer)
        assert legend_box.x0 >= fig_box.x0 and legend_box.y0 >= fig_box.y0
    finally:
        plt.close(fig)


def test_plot_rig_writes_one_png_and_no_temporary(tmp_path):
    out = plot_rig(_outward_ring(), tmp_path / "sub" / "rig.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out.parent.iterdir()) == ["rig.png"]

