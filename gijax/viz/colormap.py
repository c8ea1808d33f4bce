"""Colour-mapped images of scalar panoramas (distance, inverse distance, uncertainty).

Only this module and the writers touch matplotlib, always with the Agg backend (no display).
Files are written to a temporary name and renamed, so a partial PNG never looks complete.
"""

from __future__ import annotations

import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import numpy as np  # noqa: E402

from gijax.io.paths import save_figure_atomic  # noqa: E402


def colorize(values: np.ndarray, vmin: float, vmax: float, cmap: str = "turbo",
             valid: np.ndarray | None = None, invalid_dim: float = 0.35) -> np.ndarray:
    """(H, W) scalars -> (H, W, 3) uint8 RGB through a matplotlib colour map.

    Values are clipped to [vmin, vmax]. Pixels where ``valid`` is False keep their colour
    darkened by ``invalid_dim`` (so the estimate stays visible but is marked); non-finite
    values are black.
    """
    values = np.asarray(values, np.float64)
    if values.ndim != 2:
        raise ValueError(f"colorize expects an (H, W) array; found shape {values.shape}")
    if not vmax > vmin:
        raise ValueError(f"colorize needs vmax > vmin; found vmin={vmin}, vmax={vmax}")
    finite = np.isfinite(values)
    t = np.clip((np.where(finite, values, vmin) - vmin) / (vmax - vmin), 0.0, 1.0)
    rgb = matplotlib.colormaps[cmap](t)[..., :3]
    if valid is not None:
        rgb = np.where(np.asarray(valid, bool)[..., None], rgb, rgb * invalid_dim)
    rgb = np.where(finite[..., None], rgb, 0.0)
    return (rgb * 255.0 + 0.5).astype(np.uint8)


def panorama_figure(values: np.ndarray, label: str, vmin: float, vmax: float,
                    cmap: str = "turbo", title: str = "", valid: np.ndarray | None = None,
                    ticks: dict | None = None, dpi: int = 100):
    """The figure of :func:`save_panorama_png`, left open: the panorama at its own aspect
    (W : H, 2 : 1 for the full sphere), its title above and a labelled colour bar below."""
    rgb = colorize(values, vmin, vmax, cmap, valid)
    h, w = rgb.shape[:2]
    width_in = max(6.0, w / dpi)
    lines = textwrap.wrap(title, 90) if title else []
    # Heights in inches: the image keeps the panorama's aspect across 94 % of the width; the
    # title and the colour bar (bar, ticks, label) get fixed room.
    image_h = 0.94 * width_in * h / w
    title_h = 0.15 + 0.18 * len(lines)
    bar_h = 0.95
    fig_h = bar_h + image_h + title_h
    fig = plt.figure(figsize=(width_in, fig_h))
    ax = fig.add_axes([0.03, bar_h / fig_h, 0.94, image_h / fig_h])
    ax.imshow(rgb, interpolation="nearest", aspect="auto")
    ax.set_axis_off()
    if lines:
        ax.set_title("\n".join(lines), fontsize=9)
    cax = fig.add_axes([0.1, 0.5 / fig_h, 0.8, 0.16 / fig_h])
    mappable = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(vmin, vmax),
                                            cmap=cmap)
    bar = fig.colorbar(mappable, cax=cax, orientation="horizontal")
    bar.set_label(label)
    if ticks:
        kept: dict = {}
        span = vmax - vmin

        # The ends of the bar first, then the rest from the top down.
        def priority(p):
            return (min(abs(p - vmin), abs(p - vmax)) > 1e-9 * span, -p)

        for pos in sorted(ticks, key=priority):
            if all(abs(pos - k) >= 0.06 * span for k in kept):
                kept[pos] = ticks[pos]
        order = sorted(kept)
        bar.set_ticks(order)
        bar.set_ticklabels([kept[k] for k in order])
    return fig


def save_panorama_png(path: str, values: np.ndarray, label: str, vmin: float, vmax: float,
                      cmap: str = "turbo", title: str = "", valid: np.ndarray | None = None,
                      ticks: dict | None = None, dpi: int = 100) -> str:
    """Write an (H, W) panorama as a colour-mapped PNG at the panorama's own aspect with a
    labelled colour bar (:func:`panorama_figure`).

    ``ticks`` optionally maps colour-bar positions (in ``values`` units) to tick labels, e.g.
    inverse distances labelled in metres; ticks closer than 6 % of the bar to a kept one are
    dropped. Pixels where ``valid`` is False are darkened. Returns ``path``.
    """
    fig = panorama_figure(values, label, vmin, vmax, cmap, title, valid, ticks, dpi)
    try:
        save_figure_atomic(fig, path, dpi=dpi, format="png")
    finally:
        plt.close(fig)
    return path
