"""The candidate figure: feature displacement per step for EV and GI lists (writes a PNG).

Panels: the closed-form geometry (one perpendicular baseline) at the training spacing and at
1 m, in degrees of parallax per step; optionally a rig panel with the rig-aware mean
displacement per step (pixels or radians) of EV, the training GI list and the rig's own GI list.
"""

from __future__ import annotations

import os

import numpy as np

from gijax.candidates import (MEASURE_UNITS, TRAIN_BASELINE, closed_form_steps, ev_candidates,
                              gi_candidates, rig_gi_candidates, step_uniformity)
from gijax.io.paths import save_figure_atomic


def _closed_panel(ax, n, d_min, d_max, baseline, title):
    ev = ev_candidates(n, d_min, d_max)
    lists = [("EV", ev, "tab:blue", "o"),
             (f"GI (b = {baseline:.3g} m)", gi_candidates(n, d_min, d_max, baseline), "tab:red",
              "s")]
    if abs(baseline - TRAIN_BASELINE) > 1e-9:
        lists.append(("GI, training list", gi_candidates(n, d_min, d_max, TRAIN_BASELINE),
                      "tab:orange", "^"))
    for label, c, color, marker in lists:
        steps = np.degrees(np.asarray(closed_form_steps(c, baseline)))
        ratio = steps.min() / steps.max()
        ax.plot(np.arange(1, n), steps, marker=marker, color=color, ms=4,
                label=f"{label}: min/max {ratio:.2f}")
    ax.set_title(title)
    ax.set_xlabel("step i (d_i -> d_i+1, near to far)")
    ax.set_ylabel("parallax change per step (deg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def _rig_panel(ax, rig, rig_name, n, d_min, d_max, measure):
    lists = [("EV", ev_candidates(n, d_min, d_max), "tab:blue", "o"),
             ("GI, training list", gi_candidates(n, d_min, d_max, TRAIN_BASELINE), "tab:orange",
              "^"),
             ("GI, this rig", rig_gi_candidates(rig, n, d_min, d_max, measure=measure), "tab:red",
              "s")]
    unit = "px"
    for label, c, color, marker in lists:
        u = step_uniformity(rig, c, measure=measure)
        unit = MEASURE_UNITS[measure]
        steps = np.asarray(u["steps"])
        ax.plot(np.arange(1, n), steps, marker=marker, color=color, ms=4,
                label=f"{label}: min/max {float(u['min_max_ratio']):.2f}, cv {float(u['cv']):.3f}")
    ax.set_title(f"rig {rig_name}: mean over rays and cameras")
    ax.set_xlabel("step i (d_i -> d_i+1, near to far)")
    ax.set_ylabel(f"feature displacement per step ({unit})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def plot_candidates(path, n: int = 16, d_min: float = 0.5, d_max: float = 100.0, rig=None,
                    rig_name: str = "rig", measure: str = "pixels", wide_baseline: float = 1.0):
    """Write the candidate figure to ``path`` (PNG); written to a temporary name, then renamed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 3 if rig is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 4.2), constrained_layout=True)
    _closed_panel(axes[0], n, d_min, d_max, TRAIN_BASELINE,
                  f"training spacing b = {TRAIN_BASELINE:.3f} m, {n} candidates")
    _closed_panel(axes[1], n, d_min, d_max, wide_baseline,
                  f"spacing b = {wide_baseline:g} m, {n} candidates")
    if rig is not None:
        _rig_panel(axes[2], rig, rig_name, n, d_min, d_max, measure)
    path = os.fspath(path)
    try:
        save_figure_atomic(fig, path, dpi=110)
    finally:
        plt.close(fig)
    return path
