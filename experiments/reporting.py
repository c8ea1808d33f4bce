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
    absolute error (1/m). ``panels`` is a list of (label, inverse distance (H, W)).

    Every panorama (truth, predictions, errors) is drawn at one size and the panorama's own
    aspect, so shapes compare across panels; the truth's row carries both colour scales."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    from gijax.evaluate.labels import usable_label

    dist = np.asarray(sample["pano_distance"], np.float64)
    valid = usable_label(dist)
    # The label as the metrics see it: inverse distance clamped to the 0.5-100 m range.
    gt = np.where(valid, np.clip(1.0 / np.maximum(dist, 1e-6), 0.01, 2.0), np.nan)
    vmax = float(np.nanpercentile(gt, 99)) if np.any(valid) else 1.0
    vmax = max(vmax, 0.05)
    images = sample["images"]
    ncam = len(images)
    h, w = gt.shape
    # Two panoramas side by side across a 10-inch figure; each map row is as tall as a
    # panorama drawn at that width (plus its title).
    map_h = 4.6 * h / w + 0.35
    rows = 1 + len(panels)
    fig = plt.figure(figsize=(10, 2.4 + map_h * rows), layout="constrained")
    outer = fig.add_gridspec(2, 1, height_ratios=[2.4, map_h * rows])
    cams = outer[0].subgridspec(1, ncam)
    for c in range(ncam):
        ax = fig.add_subplot(cams[0, c])
        ax.imshow(images[c])
        ax.set_title(f"camera {c}", fontsize=8)
        ax.axis("off")
    maps = outer[1].subgridspec(rows, 2)
    inv_scale = dict(cmap="turbo", vmin=0.0, vmax=vmax)
    err_scale = dict(cmap="magma", vmin=0.0, vmax=0.25 * vmax)
    ax = fig.add_subplot(maps[0, 0])
    ax.imshow(gt, aspect="equal", **inv_scale)
    ax.set_title("ground truth inverse distance (1/m)", fontsize=8)
    ax.axis("off")
    # The right half of the truth's row holds the two colour scales every map below uses.
    scales = maps[0, 1].subgridspec(2, 1)
    for k, (scale, label) in enumerate([(inv_scale, "inverse distance (1/m): truth, predictions"),
                                        (err_scale, "|error| (1/m)")]):
        cax = fig.add_subplot(scales[k])
        bar = fig.colorbar(ScalarMappable(Normalize(scale["vmin"], scale["vmax"]),
                                          scale["cmap"]), cax=cax, orientation="horizontal")
        bar.ax.tick_params(labelsize=7)
        bar.set_label(label, fontsize=7)
    for r, (label, inv) in enumerate(panels):
        inv = np.asarray(inv, np.float64)
        err = np.where(valid, np.abs(inv - gt), np.nan)
        ax = fig.add_subplot(maps[1 + r, 0])
        ax.imshow(inv, aspect="equal", **inv_scale)
        ax.set_title(f"{label}: prediction", fontsize=7)
        ax.axis("off")
        ax = fig.add_subplot(maps[1 + r, 1])
        ax.imshow(err, aspect="equal", **err_scale)
        ax.set_title(f"{label}: |error|, MAE {np.nanmean(err):.4f} 1/m", fontsize=7)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    save_png(fig, path, dpi=90)
    plt.close(fig)
