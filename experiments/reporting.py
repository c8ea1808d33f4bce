"""What the experiment scripts write: progress lines, table cells, ``<out>.md`` / ``<out>.json``,
sections of ``RESULTS.md`` and the prediction figures. Every file is written atomically by
:mod:`gijax.io.paths` (``write_text``, ``write_json`` and ``save_png`` are its writers under
the names the scripts use), so an interrupted script never leaves half a table.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gijax.io.paths import save_figure_atomic as save_png
from gijax.io.paths import write_json_atomic as write_json
from gijax.io.paths import write_text_atomic as write_text


def log(msg: str) -> None:
    print(msg, flush=True)


def read_json(path: Path):
    """The JSON document at ``path``, or None when it is missing or unreadable."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def fmt(v, digits: int = 4) -> str:
    """A table cell: '-' for a missing or non-finite value, floats to ``digits`` decimals."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def save_table(out_stem: Path, title: str, markdown_body: str, doc: dict) -> None:
    """``<stem>.md`` and ``<stem>.json``."""
    write_json(out_stem.with_suffix(".json"), doc)
    write_text(out_stem.with_suffix(".md"), f"# {title}\n\n{markdown_body}\n")


def check_results_section(results_md: Path, section: str) -> None:
    """ValueError unless ``results_md`` holds the markers of ``section``: a script checks
    this before its work, so a missing section costs no rerun."""
    text = results_md.read_text()
    begin, end = f"<!-- {section}:begin -->", f"<!-- {section}:end -->"
    if begin not in text or end not in text:
        raise ValueError(f"{results_md} has no '{begin}' ... '{end}' markers")


def update_results_section(results_md: Path, section: str, body: str) -> None:
    """Replace the text between ``<!-- section:begin -->`` and ``<!-- section:end -->``."""
    check_results_section(results_md, section)
    text = results_md.read_text()
    begin, end = f"<!-- {section}:begin -->", f"<!-- {section}:end -->"
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    write_text(results_md, f"{head}{begin}\n{body.strip()}\n{end}{tail}")


def publish_section(results_md: Path, section: str, body: str, figures) -> None:
    """:func:`update_results_section` with the links to ``figures`` (paths) that lie beside
    ``results_md`` made relative to it (the document links them by file name)."""
    base = results_md.resolve().parent
    for fig in figures:
        fig = Path(fig)
        if fig.resolve().is_relative_to(base):
            body = body.replace(f"]({fig.name})", f"]({fig.resolve().relative_to(base)})")
    update_results_section(results_md, section, body)
    log(f"updated the {section} section of {results_md}")


def save_figure(path: Path, sample: dict, panels: list, title: str) -> None:
    """Input fisheyes, ground-truth inverse distance, then one row per method: prediction and
    absolute error (1/m). ``panels`` is a list of (label, inverse distance (H, W))."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gijax.evaluate.labels import usable_label

    dist = np.asarray(sample["pano_distance"], np.float64)
    valid = usable_label(dist)
    # The label as the metrics see it: inverse distance clamped to the 0.5-100 m range.
    gt = np.where(valid, np.clip(1.0 / np.maximum(dist, 1e-6), 0.01, 2.0), np.nan)
    vmax = float(np.nanpercentile(gt, 99)) if np.any(valid) else 1.0
    vmax = max(vmax, 0.05)
    images = sample["images"]
    ncam = len(images)
    rows = 2 + len(panels)
    fig = plt.figure(figsize=(10, 1.3 * rows + 2.2))
    grid = fig.add_gridspec(rows, max(ncam, 2), height_ratios=[2.2] + [1.0] * (rows - 1))
    for c in range(ncam):
        ax = fig.add_subplot(grid[0, c])
        ax.imshow(images[c])
        ax.set_title(f"camera {c}", fontsize=8)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, :])
    im = ax.imshow(gt, cmap="turbo", vmin=0.0, vmax=vmax, aspect="auto")
    ax.set_title("ground truth inverse distance (1/m)", fontsize=8)
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.02, pad=0.01)
    half = max(ncam, 2) // 2
    for r, (label, inv) in enumerate(panels):
        inv = np.asarray(inv, np.float64)
        err = np.where(valid, np.abs(inv - gt), np.nan)
        ax = fig.add_subplot(grid[2 + r, :half])
        ax.imshow(inv, cmap="turbo", vmin=0.0, vmax=vmax, aspect="auto")
        ax.set_title(f"{label}: prediction", fontsize=7)
        ax.axis("off")
        ax = fig.add_subplot(grid[2 + r, half:])
        im = ax.imshow(err, cmap="magma", vmin=0.0, vmax=0.25 * vmax, aspect="auto")
        ax.set_title(f"{label}: |error|, MAE {np.nanmean(err):.4f} 1/m", fontsize=7)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_png(fig, path, dpi=90)
    plt.close(fig)
