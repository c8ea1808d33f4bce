"""Top and side views of a rig: camera centres, field-of-view cones, the occluder, reference."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gijax.geometry.rig import Rig, pairwise_baselines
from gijax.io.paths import save_figure_atomic


def _cone_outline(rot: np.ndarray, half_angle: float, length: float, plane: tuple[int, int]):
    """The two edges of the field-of-view cone in a view plane (axes ``plane`` of the rig frame).

    The cone's edges in that plane are the optical axis rotated by +-half_angle inside the
    plane spanned by the axis and the plane's in-view direction most perpendicular to it.
    """
    axis = rot[:, 2]
    a2 = axis[list(plane)]
    if np.linalg.norm(a2) < 1e-6:  # looking straight out of the view plane
        a2 = np.array([0.0, 1.0])
    a2 = a2 / np.linalg.norm(a2)
    perp = np.array([-a2[1], a2[0]])
    h = min(half_angle, math.pi)
    edges = [length * (math.cos(h) * a2 + s * math.sin(h) * perp) for s in (-1.0, 1.0)]
    return edges, a2 * length


def plot_rig(rig: Rig, path, title: str | None = None) -> Path:
    """Write a PNG with the rig seen from the top (x-y) and the side (x-z)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle, Wedge

    t = np.asarray(rig.translations, np.float64)
    rots = np.asarray(rig.rotations, np.float64)
    ref = np.asarray(rig.reference, np.float64)
    span = max(float(pairwise_baselines(rig).max()), 0.1)
    length = 0.35 * span
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.6))
    colours = plt.cm.tab10(np.arange(rig.num_cameras) % 10)
    views = [((0, 1), "top view (rig x-y plane; z = viewing axis, out of the page)", "x (m)",
              "y (m)"),
             ((0, 2), "side view (rig x-z plane)", "x (m)", "z (m), viewing axis")]
    for ax, (plane, name, xl, yl) in zip(axes, views):
        i0, i1 = plane
        occ = rig.occluder
        if occ is not None:
            if plane == (0, 1):
                ax.add_patch(Circle((float(occ.x), float(occ.y)), float(occ.radius),
                                    color="0.45", alpha=0.8, label="occluder"))
            else:
                ax.add_patch(Rectangle((float(occ.x) - float(occ.radius), float(occ.z_min)),
                                       2 * float(occ.radius), float(occ.z_max) - float(occ.z_min),
                                       color="0.45", alpha=0.8, label="occluder"))
        for i, cam in enumerate(rig.cameras):
            c = t[i, [i0, i1]]
            half = 0.5 * float(cam.fov)
            axis = rots[i][:, 2]
            col = colours[i]
            if plane == (0, 1) and abs(axis[2]) > 0.99:
                # The cone points out of the page: a ring marks the axis (the side view
                # shows the cone's opening).
                ax.add_patch(Circle(tuple(c), 0.25 * length, fill=True, alpha=0.15, color=col))
                ax.add_patch(Circle(tuple(c), 0.25 * length, fill=False, lw=1.2, color=col))
            else:
                edges, ax_vec = _cone_outline(rots[i], half, length, plane)
                ang = [math.degrees(math.atan2(e[1], e[0])) for e in edges]
                ax.add_patch(Wedge(tuple(c), length, ang[0], ang[1], alpha=0.12, color=col)
                             if half < math.pi else Circle(tuple(c), length, alpha=0.12,
                                                           color=col))
                for e in edges:
                    ax.plot([c[0], c[0] + e[0]], [c[1], c[1] + e[1]], color=col, lw=0.8)
                ax.annotate("", xy=tuple(c + 0.6 * ax_vec), xytext=tuple(c),
                            arrowprops=dict(arrowstyle="->", color=col, lw=1.5))
            ax.plot(*c, "o", color=col, ms=8, mec="k",
                    label=f"{rig.names[i]} ({cam.MODEL}, fov {math.degrees(2 * half):.0f} deg)")
            ax.annotate(rig.names[i], tuple(c), textcoords="offset points", xytext=(6, 6),
                        fontsize=9)
        ax.plot(ref[i0], ref[i1], "k*", ms=14, label="reference point", zorder=5)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
        pts = np.concatenate([t[:, [i0, i1]], ref[None, [i0, i1]]])
        pad = (0.6 if plane == (0, 1) else 1.1) * length
        lo, hi = pts.min(0) - pad, pts.max(0) + pad
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        if plane == (0, 1):
            ax.invert_yaxis()  # rig y points down when seen from behind the cameras
    axes[0].legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8)
    b = pairwise_baselines(rig)
    off = b[~np.eye(len(b), dtype=bool)]
    fig.suptitle(title or f"{rig.num_cameras} cameras, baselines {off.min():.3f}-{off.max():.3f} m"
                 if len(off) else title or "1 camera")
    fig.tight_layout()
    try:
        return save_figure_atomic(fig, path, dpi=110)
    finally:
        plt.close(fig)
