"""The refinement's loss curve as a PNG (an edge: writes a file atomically)."""

from __future__ import annotations

from pathlib import Path


def plot_loss_curve(history: list, path, title: str = "calibration refinement") -> str:
    """Objective and photometric data term per step, the blur levels shaded; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gijax.io.paths import atomic_path

    steps = [h["step"] for h in history]
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.plot(steps, [h["loss"] for h in history], lw=0.9, label="objective")
    ax.plot(steps, [h["data"] for h in history], lw=0.9, label="photometric data term")
    levels = sorted({h["level"] for h in history})
    for lv in levels[1:]:
        first = min(h["step"] for h in history if h["level"] == lv)
        ax.axvline(first, color="0.6", lw=0.6, ls="--")
    ax.set_xlabel("step (dashed: next, finer blur level)")
    ax.set_ylabel("loss")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return str(path)
