"""Top and side views of a rig: camera centres, fields of view, the occluder, the reference point.

The views are drawn in the rig's panorama frame (``Rig.panorama_rotation``, chosen by
``--panorama`` / ``--up`` or estimated from the cameras), not in the rig's own axes: the top view
looks down the up axis (the panorama pole, out of the page) onto the plane of longitude 0 (to
the right) and the axis 90 degrees to its left (up the page), a right-handed view from above;
the side view puts the up axis vertical and longitude 0 to the right. Every axis label gives its
direction in the rig frame, so a user can match the picture to the calibration.

Each camera's field of view is what its data shows: the widest valid pixel of its mask when it
has one (calibration imports leave ``cam.fov`` at 360 degrees), otherwise the widest pixel of
its image under the lens model (:mod:`gijax.geometry.field_of_view`). The wedges are that cone
around the optical axis's direction in the view plane: a schematic, not a projection.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gijax.geometry.field_of_view import field_of_view, mask_field_of_view
from gijax.geometry.panorama_frame import panorama_rotation
from gijax.geometry.rig import Rig, pairwise_baselines
from gijax.io.paths import save_figure_atomic

# A camera axis whose in-plane part is shorter than this points (nearly) out of the view.
_OUT_OF_VIEW = 0.2
# Cameras closer than this share of the rig's extent in a view share one label there.
_SAME_SPOT = 0.03
# Points on each rim circle of the occluder cylinder, for its silhouette.
_RIM_POINTS = 64


def camera_fields_of_view(rig: Rig) -> list[tuple[float, str]]:
    """Each camera's full field of view in radians, and where it comes from ("mask", "cone" for
    a ``cam.fov`` set below the lens's reach, or "lens" for the lens model over the image)."""
    out = []
    for cam, mask in zip(rig.cameras, rig.masks):
        if mask is not None:
            out.append((float(mask_field_of_view(cam, np.asarray(mask))), "mask"))
            continue
        effective = float(field_of_view(cam).effective)
        cone = float(cam.fov)
        out.append((effective, "cone" if cone < 2 * math.pi - 1e-6 and
                    abs(effective - cone) < 1e-6 else "lens"))
    return out


def view_axes(rig: Rig) -> np.ndarray:
    """(3, 3): columns are the rig-frame directions of the views' axes: longitude 0, the axis
    90 degrees to its left, and up (the panorama pole)."""
    return np.asarray(panorama_rotation(rig), np.float64)


def _fmt(v) -> str:
    v = np.round(np.asarray(v, np.float64), 2) + 0.0    # no "-0.00"
    return "[" + ", ".join(f"{x:+.2f}" for x in v) + "]"


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D points, counter-clockwise (monotone chain)."""
    pts = sorted(map(tuple, np.round(points, 12)))
    if len(pts) < 3:
        return np.asarray(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.asarray(lower[:-1] + upper[:-1])


def _occluder_points(occ) -> np.ndarray:
    """Rig-frame points on the two rim circles of the occluder cylinder (axis along rig z)."""
    a = np.linspace(0.0, 2 * math.pi, _RIM_POINTS, endpoint=False)
    ring = np.stack([float(occ.x) + float(occ.radius) * np.cos(a),
                     float(occ.y) + float(occ.radius) * np.sin(a)], -1)
    return np.concatenate([np.concatenate([ring, np.full((_RIM_POINTS, 1), z)], -1)
                           for z in (float(occ.z_min), float(occ.z_max))])


def _label_groups(xy: np.ndarray, span: float) -> list[list[int]]:
    """Cameras grouped by where they fall in a view (one label per spot)."""
    groups: list[list[int]] = []
    for i, p in enumerate(xy):
        for g in groups:
            if np.linalg.norm(xy[g[0]] - p) < _SAME_SPOT * span:
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


def rig_figure(rig: Rig, title: str | None = None):
    """The matplotlib figure of :func:`plot_rig` (top view, side view, legend), left open."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Patch, Polygon, Wedge

    frame = view_axes(rig)
    origin = np.asarray(rig.reference, np.float64)
    # Positions and directions in view coordinates: (longitude 0, left, up).
    centres = (np.asarray(rig.translations, np.float64) - origin) @ frame
    optical = np.asarray(rig.rotations, np.float64)[:, :, 2] @ frame
    span = max(float(pairwise_baselines(rig).max()), 0.1)
    length = 0.35 * span
    fovs = camera_fields_of_view(rig)
    occ = rig.occluder
    occ_view = None if occ is None else (_occluder_points(occ) - origin) @ frame
    colours = plt.cm.tab10(np.arange(rig.num_cameras) % 10)

    fig, axes = plt.subplots(1, 2, figsize=(12, 6), layout="compressed")
    views = [((0, 1), f"top view: up {_fmt(frame[:, 2])} out of the page",
              f"left of longitude 0, {_fmt(frame[:, 1])} (m)"),
             ((0, 2), f"side view: up {_fmt(frame[:, 2])} vertical",
              f"up, {_fmt(frame[:, 2])} (m)")]
    for ax, (plane, name, ylabel) in zip(axes, views):
        i0, i1 = plane
        out_axis = 3 - i0 - i1
        extent = [np.zeros((1, 2))]
        if occ_view is not None:
            hull = _hull(occ_view[:, [i0, i1]])
            ax.add_patch(Polygon(hull, closed=True, color="0.45", alpha=0.8, zorder=1))
            extent.append(hull)
        for i in range(rig.num_cameras):
            c = centres[i, [i0, i1]]
            col = colours[i]
            half = min(0.5 * fovs[i][0], math.pi)
            a2 = optical[i, [i0, i1]]
            extent.append(c[None])
            if np.linalg.norm(a2) < _OUT_OF_VIEW:
                # The axis points out of (solid ring) or into (dashed ring) the page.
                toward = optical[i, out_axis] > 0
                ax.add_patch(Circle(tuple(c), 0.25 * length, alpha=0.15, color=col, zorder=2))
                ax.add_patch(Circle(tuple(c), 0.25 * length, fill=False, lw=1.2, color=col,
                                    ls="-" if toward else "--", zorder=2))
                extent.append(c[None] + 0.25 * length * np.array([[-1, -1], [1, 1]]))
                continue
            a2 = a2 / np.linalg.norm(a2)
            centre_deg = math.degrees(math.atan2(a2[1], a2[0]))
            if half >= math.pi - 1e-6:
                ax.add_patch(Circle(tuple(c), length, alpha=0.12, color=col, zorder=2))
            else:
                ax.add_patch(Wedge(tuple(c), length, centre_deg - math.degrees(half),
                                   centre_deg + math.degrees(half), alpha=0.12, color=col,
                                   zorder=2))
                for s in (-1.0, 1.0):
                    edge = length * np.array([math.cos(math.radians(centre_deg) + s * half),
                                              math.sin(math.radians(centre_deg) + s * half)])
                    ax.plot([c[0], c[0] + edge[0]], [c[1], c[1] + edge[1]], color=col, lw=0.8,
                            zorder=2)
            ax.annotate("", xy=tuple(c + 0.6 * length * a2), xytext=tuple(c),
                        arrowprops=dict(arrowstyle="->", color=col, lw=1.5), zorder=3)
            extent.append(c[None] + length * np.array([[-1, -1], [1, 1]]))
        ax.plot(0.0, 0.0, "k*", ms=14, zorder=5)
        for i in range(rig.num_cameras):
            ax.plot(*centres[i, [i0, i1]], "o", color=colours[i], ms=8, mec="k", zorder=4)
        xy = centres[:, [i0, i1]]
        middle = xy.mean(axis=0)
        for group in _label_groups(xy, span):
            c = xy[group[0]]
            away = c - middle
            away = away / np.linalg.norm(away) if np.linalg.norm(away) > 1e-9 else np.ones(2)
            ax.annotate(", ".join(rig.names[i] for i in group), tuple(c),
                        textcoords="offset points", xytext=tuple(10 * away), fontsize=9,
                        ha="left" if away[0] >= 0 else "right",
                        va="bottom" if away[1] >= 0 else "top", zorder=6,
                        bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
        pts = np.concatenate(extent)
        pad = 0.15 * span
        lo, hi = pts.min(0) - pad, pts.max(0) + pad
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(f"longitude 0, {_fmt(frame[:, 0])} (m)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)

    source = {"mask": "its mask", "cone": "set cone", "lens": "lens model over the image"}
    handles = [Line2D([], [], marker="o", ls="", color=colours[i], mec="k", ms=8,
                      label=f"{rig.names[i]}: {cam.MODEL}, fov {math.degrees(fovs[i][0]):.0f} "
                            f"deg ({source[fovs[i][1]]})")
               for i, cam in enumerate(rig.cameras)]
    handles.append(Line2D([], [], marker="*", ls="", color="k", ms=12,
                          label=f"reference point {_fmt(origin)} (panorama centre)"))
    if occ is not None:
        handles.append(Patch(color="0.45", alpha=0.8, label="occluder"))
    b = pairwise_baselines(rig)
    off = b[~np.eye(len(b), dtype=bool)]
    summary = (f"{rig.num_cameras} cameras, baselines {off.min():.3f}-{off.max():.3f} m"
               if len(off) else "1 camera")
    fig.suptitle(f"{title}: {summary}" if title else summary)
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=9, frameon=False)
    return fig


def plot_rig(rig: Rig, path, title: str | None = None) -> Path:
    """Write a PNG with the rig seen from above (down its up axis) and from the side."""
    import matplotlib.pyplot as plt

    fig = rig_figure(rig, title)
    try:
        return save_figure_atomic(fig, path, dpi=110, bbox_inches="tight", pad_inches=0.15)
    finally:
        plt.close(fig)
