"""Figure of a designed layout: top view in its footprint, cameras per ray, convergence."""

from __future__ import annotations

import math
from pathlib import Path

import jax
import numpy as np

from gijax.design.objective import camera_counts, layout_pose
from gijax.design.spec import DesignSpec, Layout
from gijax.geometry.panorama import Panorama
from gijax.io.paths import save_figure_atomic


def plot_design(layout: Layout, spec: DesignSpec, path, history=None, title: str = "",
                count_pano: Panorama = Panorama.hemisphere(45, 180)) -> Path:
    """Write a PNG: (1) top view with the footprint, the occluder and its clearance, each
    camera's minimum-separation disc and optical-axis tilt; (2) how many cameras see each
    panorama ray (``count_pano`` grid); (3) the penalised objective per start vs step when
    ``history`` (steps + 1, K) is given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    rot, trans, ref = (np.asarray(x, np.float64) for x in layout_pose(layout, spec))
    counts = np.asarray(jax.jit(camera_counts, static_argnames="spec")(
        layout, spec.replace(pano=count_pano)))
    ncol = 3 if history is not None else 2
    fig, axes = plt.subplots(1, ncol, figsize=(5.2 * ncol, 4.8),
                             gridspec_kw={"width_ratios": [1, 1.6, 1.1][:ncol]})
    ax = axes[0]
    h = spec.half_size
    if spec.shape == "square":
        ax.add_patch(Rectangle((-h, -h), 2 * h, 2 * h, fill=False, lw=1.5, ls="--",
                               label=f"footprint {spec.footprint:g} m square"))
    else:
        ax.add_patch(Circle((0, 0), h, fill=False, lw=1.5, ls="--",
                            label=f"footprint {spec.footprint:g} m disc"))
    ax.add_patch(Circle((0, 0), spec.occluder_radius, color="0.4", label="occluder"))
    ax.add_patch(Circle((0, 0), spec.occluder_radius + spec.occluder_clearance, fill=False,
                        color="0.4", ls=":", lw=1))
    colours = plt.cm.tab10(np.arange(spec.num_cameras) % 10)
    for i in range(spec.num_cameras):
        c = trans[i, :2]
        ax.add_patch(Circle(tuple(c), 0.5 * spec.min_separation, fill=False, color=colours[i],
                            lw=0.8, alpha=0.6))
        axis = rot[i][:, 2]
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, axis[2]))))
        ax.plot(*c, "o", color=colours[i], mec="k", ms=9,
                label=f"cam{i} ({c[0]:+.2f}, {c[1]:+.2f}) tilt {tilt:.1f} deg")
        if np.linalg.norm(axis[:2]) > 1e-6:
            ax.annotate("", xy=tuple(c + 0.5 * h * axis[:2] / max(np.linalg.norm(axis[:2]), 1e-9)
                                     * math.sin(math.radians(tilt)) / math.sin(
                                         math.radians(max(spec.max_tilt_deg, 1e-3)))),
                        xytext=tuple(c), arrowprops=dict(arrowstyle="->", color=colours[i]))
    ax.plot(ref[0], ref[1], "k*", ms=12, label="reference point")
    pad = 0.25 * h
    ax.set_xlim(-h - pad, h + pad)
    ax.set_ylim(-h - pad, h + pad)
    ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("top view (arrows: optical-axis tilt)", fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1)
    ax.grid(alpha=0.3)

    ax = axes[1]
    im = ax.imshow(counts, cmap="viridis", vmin=0, vmax=spec.num_cameras, aspect="auto",
                   extent=[-180, 180, 0, -90])
    fig.colorbar(im, ax=ax, label="cameras seeing the ray")
    ax.set_xlabel("longitude (deg)")
    ax.set_ylabel("latitude (deg); -90 = viewing axis")
    covered = (counts >= 2).mean()
    ax.set_title(f"cameras per panorama ray ({100 * covered:.1f}% of pixels seen by >= 2)",
                 fontsize=10)

    if history is not None:
        ax = axes[2]
        hist = np.asarray(history)
        for k in range(hist.shape[1]):
            ax.plot(hist[:, k], lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("Adam step")
        ax.set_ylabel("penalised objective (1/m)")
        ax.set_title(f"{hist.shape[1]} starts", fontsize=10)
        ax.grid(alpha=0.3, which="both")
    fig.suptitle(title or f"{spec.num_cameras}-camera layout", fontsize=11)
    fig.tight_layout()
    try:
        return save_figure_atomic(fig, path, dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)
