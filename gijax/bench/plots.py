"""Scaling curves (PNG, matplotlib's Agg backend): forward time against cameras and
candidates, with the inter-quartile range as error bars."""

from __future__ import annotations

import os
from pathlib import Path

from gijax.io.paths import save_figure_atomic


def scaling_figure(result: dict, path: str | os.PathLike, rtss: dict | None = None) -> Path:
    """Draw the ``scaling`` case (and the RTSS per-camera rows, when given) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    d0 = max(set(r["candidates"] for r in rows), key=[r["candidates"] for r in rows].count)
    c0 = min(r["cameras"] for r in rows)
    cams = sorted((r for r in rows if r["candidates"] == d0), key=lambda r: r["cameras"])
    cands = sorted((r for r in rows if r["cameras"] == c0), key=lambda r: r["candidates"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))

    def curve(ax, data, xkey, ykey, label, marker="o", err=True):
        x = [r[xkey] for r in data]
        y = [r[ykey] for r in data]
        if err:
            lo = [r[ykey] - r["ms_q1"] for r in data]
            hi = [r["ms_q3"] - r[ykey] for r in data]
            ax.errorbar(x, y, yerr=[lo, hi], marker=marker, capsize=3, label=label)
        else:
            ax.plot(x, y, marker=marker, label=label)

    preset = rows[0]["preset"]
    curve(axes[0], cams, "cameras", "ms_median", f"{preset} ({d0} candidates)")
    if rtss and rtss.get("rows"):
        curve(axes[0], rtss["rows"], "cameras", "ms_median",
              f"RTSS ({rtss['rows'][0]['candidates']} candidates)", marker="s")
    axes[0].set(xlabel="cameras", ylabel="time per forward (ms, median, IQR)",
                title="time vs cameras")
    axes[0].set_xticks(sorted(set(r["cameras"] for r in cams)))
    curve(axes[1], cands, "candidates", "ms_median", f"{preset} ({c0} cameras)")
    axes[1].set(xlabel="candidates", ylabel="time per forward (ms)", title="time vs candidates")
    axes[1].set_xticks([r["candidates"] for r in cands])
    if all("xla_peak_mib" in r for r in rows):
        curve(axes[2], cams, "cameras", "xla_peak_mib", f"vs cameras ({d0} candidates)",
              err=False)
        ax2 = axes[2].twiny()
        ax2.plot([r["candidates"] for r in cands], [r["xla_peak_mib"] for r in cands], "s--",
                 color="tab:red", label=f"vs candidates ({c0} cameras)")
        ax2.set_xlabel("candidates", color="tab:red")
        axes[2].set(xlabel="cameras", ylabel="XLA peak memory (MiB)")
        axes[2].set_title("memory", pad=30)
        axes[2].set_xticks(sorted(set(r["cameras"] for r in cams)))
        axes[2].legend(loc="upper left", fontsize=8)
        ax2.legend(loc="lower right", fontsize=8)
    for ax in axes[:2]:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        return save_figure_atomic(fig, path, dpi=110)
    finally:
        plt.close(fig)
