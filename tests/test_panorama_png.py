"""Colour-mapped panorama PNGs keep the panorama's own aspect."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("hw", [(64, 128), (32, 128), (160, 640), (40, 200)])
def test_a_panorama_png_keeps_the_panoramas_aspect(hw):
    import matplotlib.pyplot as plt

    from gijax.viz.colormap import panorama_figure

    values = np.linspace(0.0, 1.0, hw[0] * hw[1]).reshape(hw)
    fig = panorama_figure(values, "1/m", 0.0, 1.0, title="a title " * 30)
    try:
        fig.canvas.draw()
        box = fig.axes[0].get_window_extent()
        assert box.width / box.height == pytest.approx(hw[1] / hw[0], rel=0.01)
        # Title and colour bar stay inside the figure.
        for artist in (fig.axes[0].title, fig.axes[1]):
            extent = artist.get_window_extent()
            assert extent.y0 >= 0 and extent.y1 <= fig.bbox.y1
    finally:
        plt.close(fig)
