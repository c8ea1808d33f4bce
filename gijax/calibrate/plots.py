"""The refinement's loss curve as a PNG (an edge: writes a file atomically)."""

from __future__ import annotations

from pathlib import Path


def plot_loss_curve(history: list, path, title: str = "calibration refinement") -> str:
    """Objective and photometric data term per step, each next blur level marked by a dashed
    line and each next round (history entries with ``round``) by a solid one; returns the
    path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gijax.io.paths import atomic_path

    steps = [h["step"] for h in history]
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.plot(steps, [h["loss"] for h in history], lw=0.9, label="objective")
    ax.plot(steps, [h["data"] for h in history], lw=0.9, label="photometric data term")
    for prev, h in zip(history, history[1:]):
        if h.get("round", 0) != prev.get("round", 0):
            ax.axvline(h["step"], color="0.3", lw=0.9)
        elif h["level"] != prev["level"]:
            ax.axvline(h["step"], color="0.6", lw=0.6, ls="--")
    rounds = len({h.get("round", 0) for h in history})
    ax.set_xlabel("step (dashed: next, finer blur level"
                  + ("; solid: next round)" if rounds > 1 else ")"))
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
