"""The demo: fresh scenes on the training rig and on a new 4-camera rig, every method, one figure.

For each rig it renders a new scene with exact labels, runs the bundled learned model (with its
training candidates, with the paper's list recomputed for the rig, the closed-form GI at the
rig's camera spacing, and with gijax's rig-aware GI list) and the classical RTSS baseline,
prints MAE / RMSE / SSIM (the paper's definitions, :mod:`gijax.evaluate.metrics`, scored by
:func:`gijax.evaluate.loop.evaluate_predictions`) and time, writes
one figure (inputs, ground truth, predictions, error maps) and a coloured point cloud of the
learned prediction on the training rig.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from gijax.io.paths import save_figure_atomic, write_json_atomic

# The bundled model the demo runs unless told otherwise (gijax/assets, see 'gijax models').
DEFAULT_MODEL = "G16VV-cpu"
DEMO_RIGS = ("paper-train", "paper-test3")


@dataclasses.dataclass
class MethodResult:
    name: str
    inv_distance: np.ndarray  # (H, W) 1/m, NaN where the method gives nothing
    seconds: float
    metrics: dict


def _evaluate(predictor, rig, sample, candidates) -> tuple[np.ndarray, float, dict, object]:
    """One method on the demo's scene: (inverse distance, NaN where it gives nothing; wall
    seconds of the call, first-call compilation included; the paper's metrics; the
    prediction)."""
    from gijax.evaluate.loop import evaluate_predictions

    made = {}

    def run(_batch):
        pred = predictor.predict(rig, sample["images"], sample["masks"])
        made["pred"] = pred
        return pred.replace(inv_distance=pred.inv_distance[None], valid=pred.valid[None])

    # Pixels a method leaves empty are scored by coverage, not by a made-up value; SSIM needs
    # a full image, so empty pixels take the method's own mean there.
    result = evaluate_predictions([{"distance": sample["pano_distance"][None]}], run,
                                  np.asarray(candidates, np.float32), holes="unscored_mean")
    pred = made["pred"]
    metrics = {**result.metrics["paper"], "coverage": result.label_coverage}
    inv = np.where(pred.valid, pred.inv_distance, np.nan)
    return inv, result.seconds[0], metrics, pred


def run_demo(out_dir: str | os.PathLike = "gijax-demo", seed: int | None = None,
             model: str | os.PathLike = DEFAULT_MODEL, rigs=DEMO_RIGS,
             baseline: str = "RS-E32", progress: bool = True) -> dict:
    """Run the demo and write ``demo.png``, ``points.ply`` and ``demo.json`` to ``out_dir``.

    ``model`` is a training run folder, an inference bundle or the name of a bundled model.
    ``seed`` None draws a fresh scene each run (the seed used is printed and saved).
    Returns the metrics table as a dict ``{rig: {method: metrics}}``.
    """
    from tqdm import tqdm

    from gijax.candidates import rig_gi_candidates, spacing_gi_candidates
    from gijax.geometry.layouts import builtin_rig
    from gijax.geometry.panorama_frame import panorama_rotation
    from gijax.geometry.rig import scale_rig
    from gijax.model import model_panorama
    from gijax.predict import LearnedPredictor, RtssPredictor
    from gijax.render import render_sample
    from gijax.store import load_model
    from gijax.viz.pointcloud import panorama_points, write_ply

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    seed = int(np.random.SeedSequence().entropy % (2**31)) if seed is None else int(seed)
    net, config, train_cand = load_model(model)
    # The paper's rigs look along one axis: the model's own panorama, the hemisphere around it.
    pano = model_panorama(config)

    steps = len(rigs) * 5
    bar = tqdm(total=steps, desc="demo", disable=not progress, unit="step")
    table: dict = {}
    panels = []
    cloud = None
    for k, name in enumerate(rigs):
        rig = builtin_rig(name)
        small = scale_rig(rig, config.image_scale)
        bar.set_postfix_str(f"{name}: rendering")
        sample = render_sample(small, seed + k, pano=pano)
        bar.update(1)
        methods = []
        # The paper's recomputed list (closed form at the rig's camera spacing) first, then
        # gijax's rig-aware list (docs/candidates.md); on the training rig the paper's list is
        # the training list itself.
        n = config.num_candidates
        cands = {"training candidates": np.asarray(train_cand),
                 "paper's GI at camera spacing": np.asarray(spacing_gi_candidates(rig, n)),
                 "rig-aware GI (gijax)": np.asarray(rig_gi_candidates(rig, n))}
        for label, cand in cands.items():
            bar.set_postfix_str(f"{name}: {config.name} ({label})")
            inv, secs, metrics, res = _evaluate(LearnedPredictor(net, cand, pano), small, sample,
                                                cand)
            methods.append(MethodResult(f"{config.name} {label}", inv, secs, metrics))
            if cloud is None:
                cloud = (res, small)
            bar.update(1)
        bar.set_postfix_str(f"{name}: {baseline}")
        # The baseline's figures are on the model's training range, like the learned rows.
        inv, secs, metrics, _ = _evaluate(RtssPredictor(baseline, pano=pano, colours=False),
                                          small, sample, train_cand)
        methods.append(MethodResult(baseline, inv, secs, metrics))
        bar.update(1)
        table[name] = {m.name: {**m.metrics, "seconds": m.seconds} for m in methods}
        panels.append((name, sample, methods))
    bar.close()

    res, small = cloud
    points, keep = panorama_points(res["distance"], np.asarray(small.reference), pano,
                                   valid=res["valid"], max_distance=50.0,
                                   rotation=panorama_rotation(small))
    colours = np.clip(res["colour"][keep] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    write_ply(str(out_dir / "points.ply"), points, colours)
    _figure(out_dir / "demo.png", panels, train_cand)
    write_json_atomic(out_dir / "demo.json", {"seed": seed, "model": str(model), "table": table})
    print(format_table(table, seed))
    print(model_note(model, config.name))
    print(f"wrote {out_dir / 'demo.png'}, {out_dir / 'points.ply'}, {out_dir / 'demo.json'}")
    return table


def model_note(model, name: str) -> str:
    """What the model was trained on and where it is expected to fail, from its provenance
    (bundles record both; a run folder is named as it is)."""
    from gijax.store import resolve_model_path
    from gijax.store.assets import limitations, trained_on
    from gijax.store.bundles import is_bundle, read_provenance

    path = resolve_model_path(model)
    if not is_bundle(path):
        return f"model {name}: the training run {path}"
    prov = read_provenance(path)
    return (f"model {name}: trained on {trained_on(prov)}\n"
            f"expected to fail on: {limitations(prov)}")


def format_table(table: dict, seed: int) -> str:
    lines = [f"scene seed {seed}; inverse distance metrics in 1/m as the paper defines them "
             f"(lower MAE/RMSE is better)",
             f"{'rig':<12} {'method':<40} {'MAE':>7} {'RMSE':>7} {'SSIM':>6} {'cover':>6} "
             f"{'time s':>7}"]
    for rig, methods in table.items():
        for name, m in methods.items():
            lines.append(f"{rig:<12} {name:<40} {m['mae']:7.4f} {m['rmse']:7.4f} "
                         f"{m['ssim']:6.3f} {m['coverage']:6.1%} {m['seconds']:7.2f}")
    lines.append("time: wall seconds of one run, including its first-call compilation")
    return "\n".join(lines)


def _figure(path: Path, panels, candidates) -> None:
    """Per rig: the camera images, then ground truth and every method's panorama beside its
    absolute error (inverse distance, 1/m; shared colour scales)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    vmin, vmax = 1.0 / float(np.max(candidates)), 1.0 / float(np.min(candidates))
    rows = sum(3 + len(methods) for _, _, methods in panels)
    fig = plt.figure(figsize=(12, 1.55 * rows + 0.8))
    outer = fig.add_gridspec(rows, 2, hspace=0.55, wspace=0.06, left=0.02, right=0.98,
                             top=0.97, bottom=0.07)
    r = 0
    im = em = None
    for name, sample, methods in panels:
        cams = fig.add_gridspec(1, 2 * len(sample["images"]), left=0.02, right=0.98,
                                top=outer[r, 0].get_position(fig).y1,
                                bottom=outer[r + 1, 0].get_position(fig).y0, wspace=0.05)
        for c, image in enumerate(sample["images"]):
            ax = fig.add_subplot(cams[0, 2 * c])
            ax.imshow(image)
            ax.set_title(f"{name}: camera {c}", fontsize=8)
            ax.axis("off")
            ax = fig.add_subplot(cams[0, 2 * c + 1])
            ax.imshow(sample["masks"][c], cmap="gray", vmin=0, vmax=1)
            ax.set_title(f"mask {c}", fontsize=8)
            ax.axis("off")
        r += 2
        gt = 1.0 / np.clip(sample["pano_distance"], 1e-3, None)
        rows_here = [("ground truth", gt, None)] + [
            (f"{m.name} (MAE {m.metrics['mae']:.3f})", m.inv_distance,
             np.abs(m.inv_distance - np.clip(gt, vmin, vmax))) for m in methods]
        for title, pano, err in rows_here:
            ax = fig.add_subplot(outer[r, 0])
            im = ax.imshow(pano, cmap="turbo", vmin=vmin, vmax=vmax, aspect="auto")
            ax.set_title(f"{name}: {title}", fontsize=8)
            ax.axis("off")
            ax = fig.add_subplot(outer[r, 1])
            if err is None:
                ax.axis("off")
            else:
                em = ax.imshow(err, cmap="magma", vmin=0, vmax=0.5, aspect="auto")
                ax.set_title("absolute error", fontsize=8)
                ax.axis("off")
            r += 1
    cax = fig.add_axes([0.06, 0.025, 0.38, 0.012])
    fig.colorbar(im, cax=cax, orientation="horizontal", label="inverse distance (1/m)")
    cax = fig.add_axes([0.56, 0.025, 0.38, 0.012])
    fig.colorbar(em, cax=cax, orientation="horizontal", label="absolute error (1/m)")
    try:
        save_figure_atomic(fig, path, dpi=80)
    finally:
        plt.close(fig)
