"""Label-free adaptation of the bundled network to a rig it never saw, scored with labels.

The bundled model (by default the one the demo runs; ``--model`` names another) was trained on
3-4 camera rigs facing one way. This script takes the 5-camera ring ``ring5-0.5m``
(``experiments/learned_candidates.py``: a regular pentagon, 0.5 m between neighbours; more
cameras than any rig of the bundle's mixture) and:

1. renders ``frames`` scenes of the ring (seed 701) whose images alone are used (labels never
   reach a loss: ``gijax adapt`` builds its training arrays without them), and ``test``
   held-out scenes (seed 702) whose labels only score;
2. scores, on the held-out scenes, the bundle before adapting (its training list, and the
   list recomputed for the ring's spacing: the paper's way of moving a model to a new rig
   without training), and the classical baseline RS-E32;
3. adapts the bundle on the frames with ``gijax adapt`` (:func:`gijax.train.rig_adaptation.
   adapt_network`): with the photometric and smoothness terms comparing every camera that
   images a point, the same leaving out the cameras a nearer predicted point hides it from
   (``--occlusion``, the default), and that with RS-E32 as a teacher where it is confident;
   the held-out labels logged as validation (never part of the objective, never used to
   choose a checkpoint: the bundle is the last step's);
4. scores the adapted bundles, and compares scene by scene (paired bootstrap of the per-scene
   MAE differences, :func:`experiments.claims.paired_difference`): adapted vs before, the
   occlusion test vs none, and the teacher-adapted model vs its teacher.

Claims: MAE after adaptation lower than before; with the teacher, lower than the teacher's.

Writes ``<out>.md``, ``<out>.json``, ``<out>_maps.png`` (the first held-out scene: truth, RTSS,
before, after) and ``<out>_curves.png`` (adaptation loss and held-out MAE per step); for
``--scale cpu`` into ``experiments/results/network_adaptation_cpu*`` and a section of
``experiments/RESULTS.md``. Data, adaptation runs and evaluations live in the work folder and
are reused (a run resumes where it stopped; an evaluation is keyed by the weights' hash).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.arguments import (add_common_arguments, resolve_paths,  # noqa: E402
                                   script_parser)
from experiments.claims import paired_difference, paired_text  # noqa: E402
from experiments.evaluation import (cached_evaluation, model_id, net_predictor,  # noqa: E402
                                    rtss_predictor, weights_id)
from experiments.learned_candidates import RING, ring_rig  # noqa: E402
from experiments.provenance import command_line, revision  # noqa: E402
from experiments.reporting import (fmt, log, publish_section, save_figure, save_png,  # noqa: E402
                                   write_json, write_text)
from experiments.workfolder import (dataset_seeds, gijax_command, metrics_records,  # noqa: E402
                                    render_recorded, rig_file_argument)
from gijax.bench.machine import machine_info  # noqa: E402
from gijax.geometry.visibility import OCCLUSION_MARGIN  # noqa: E402
from gijax.bench.report import markdown_grid  # noqa: E402

NAME = "network_adaptation"
SECTION = "network-adaptation"
TEACHER = "RS-E32"
PANO_HW = (32, 128)           # the bundle's output panorama (labels must match it)
SEEDS = {"frames": 701, "test": 702}
STYLE = "mixed"
SCALES = {
    # images at image_scale of 1024 px; unlabeled frames and held-out scenes; adaptation steps,
    # frames per step, learning rate (constant), teacher weight, held-out scoring interval
    "smoke": dict(image_scale=0.125, frames=2, test=2, steps=2, batch=1, lr=2e-5, teacher=1.0,
                  val_every=0, summary="pipeline check only, not evidence: 128 px images, 2 "
                                       "frames, 2 held-out scenes, 2 steps"),
    "cpu": dict(image_scale=0.25, frames=48, test=32, steps=400, batch=2, lr=5e-5, teacher=1.0,
                val_every=100, summary="256 px images, 48 unlabeled frames, 32 held-out "
                                       "scenes, 400 steps of 2 frames"),
}
# name -> (label, LabelFree weights; teacher None: the scale's teacher weight). Every variant
# weighs the photometric and smoothness terms; the labels fit the figures' panel titles.
VARIANTS = {
    "photometric": ("adapted, every camera compared",
                    dict(photometric=1.0, smoothness=0.01, teacher=0.0, occlusion=0.0)),
    "occlusion": ("adapted, occlusion-aware (the default)",
                  dict(photometric=1.0, smoothness=0.01, teacher=0.0,
                       occlusion=OCCLUSION_MARGIN)),
    "teacher": (f"adapted, occlusion-aware + {TEACHER} teacher",
                dict(photometric=1.0, smoothness=0.01, teacher=None,
                     occlusion=OCCLUSION_MARGIN)),
}
CURVE_COLOURS = {"photometric": "tab:blue", "occlusion": "tab:green", "teacher": "tab:purple"}


def ensure_data(work: Path, cfg: dict, role: str) -> dict:
    """Render (or resume, or reuse) the ring's ``role`` dataset ('frames' or 'test')."""
    out = work / "data" / f"{RING}-{role}-{cfg['image_scale']:g}"
    samples = cfg[role]
    rig_arg = rig_file_argument(work, RING, ring_rig)
    made = render_recorded(ring_rig(), rig_arg, out, samples, SEEDS[role], cfg["image_scale"],
                           PANO_HW, style=STYLE)
    return {"role": role, "rig": RING, "path": str(out), "samples": samples,
            "seed": SEEDS[role], **made}


def adapt_argv(model: str, frames: Path, out: Path, cfg: dict, weights: dict, val: Path) -> list:
    """The ``gijax adapt`` command line equivalent to :func:`adapt`'s call."""
    argv = ["adapt", "--ckpt", model, "--frames", frames, "--out", out,
            "--photometric", weights["photometric"], "--smoothness", weights["smoothness"],
            "--steps", cfg["steps"], "--lr", cfg["lr"], "--batch", cfg["batch"],
            "--seed", 0, "--max-frames", cfg["frames"], "--val", val,
            "--val-every", cfg["val_every"]]
    argv += ["--occlusion", weights["occlusion"]]
    if weights["teacher"]:
        argv += ["--teacher", weights["teacher"], "--teacher-preset", TEACHER]
    return argv


def adapt(work: Path, cfg: dict, model: str, model_id: str, name: str, frames: Path,
          test: Path) -> dict:
    """Adapt ``model`` (weights id ``model_id``) with variant ``name`` (resumes a stopped run;
    reuses a finished one). The run folder is keyed by the weights, so adapting another model
    starts afresh."""
    from gijax.train.config import load_run_config
    from gijax.train.rig_adaptation import adapt_network, work_folder
    from gijax.train.run_folder import is_resume
    from gijax.train.unlabeled import LabelFree

    weights = dict(VARIANTS[name][1])
    if weights["teacher"] is None:
        weights["teacher"] = cfg["teacher"]
    out = work / "adapted" / f"{RING}-{name}-{model_id}"
    argv = adapt_argv(model, frames, out, cfg, weights, test)
    command = gijax_command(argv)
    done = [r for r in metrics_records(work_folder(out)) if "loss" in r]
    if is_resume(work_folder(out)):
        ran = load_run_config(work_folder(out))[0].label_free
        wanted = LabelFree(**weights).to_dict()
        if ran != wanted:
            raise SystemExit(f"{name}: {work_folder(out)} was adapted with the objective {ran}, "
                             f"not this variant's {wanted}; move it away to adapt afresh")
    t0 = time.perf_counter()
    if (out / "weights.npz").is_file() and done and done[-1]["step"] >= cfg["steps"]:
        log(f"{name}: reusing {out} ({cfg['steps']} steps)")
        result = None
    else:
        log(f"{name}: {command}")
        result = adapt_network(model, [frames], out, objective=LabelFree(**weights),
                               steps=cfg["steps"], lr=cfg["lr"], batch_size=cfg["batch"],
                               seed=0, max_frames=cfg["frames"], teacher_preset=TEACHER,
                               val=test, val_every=cfg["val_every"], progress=True,
                               invocation={"command": command, "git": revision()}, log=log)
    made_at = sorted({r["git"] for r in metrics_records(work_folder(out))
                      if r.get("event") == "started" and "git" in r})
    return {"name": name, "label": VARIANTS[name][0], "bundle": str(out), "command": command,
            "reused": result is None, "made_at": made_at,
            "objective": weights, "run": str(work_folder(out)),
            "teacher_fraction": result.teacher_fraction if result else None,
            "seconds": time.perf_counter() - t0}


def objective_at_truth(model: str, frames: Path, count: int) -> dict:
    """The photometric term (mean over the first ``count`` frames) at their true distances and
    at the truth 10 % nearer and farther, without and with the occlusion test: a label-free
    objective can only lead to the truth if the truth is where it is least. The labels are
    read here to score the objective, never to adapt."""
    import jax
    import jax.numpy as jnp

    from gijax.data import DatasetReader
    from gijax.model import model_panorama, model_rig
    from gijax.store import load_model
    from gijax.train.rig_adaptation import frame_arrays
    from gijax.train.unlabeled import LabelFree, label_free_terms

    _, mc, _ = load_model(model)
    reader = DatasetReader(frames)
    run_rig, arrays, *_ = frame_arrays([str(frames)], reader.rig, mc, calibrated=False,
                                       max_frames=count)
    pano, rig = model_panorama(mc), model_rig(run_rig)
    truth = np.stack([np.asarray(reader[i]["pano_distance"], np.float32) for i in range(count)])
    if truth.shape[1:] != pano.shape:
        raise ValueError(f"{frames}: labels {truth.shape[1:]} differ from the model's panorama "
                         f"{pano.shape}")
    labelled = np.isfinite(truth) & (truth > 0)
    inv = np.where(labelled, 1.0 / np.where(labelled, truth, 1.0), np.nan)
    inv = np.where(labelled, inv, np.nanmedian(inv)).astype(np.float32)
    out = {"frames": count}
    for margin in (0.0, OCCLUSION_MARGIN):
        objective = LabelFree(photometric=1.0, smoothness=0.0, occlusion=margin)
        term = jax.jit(lambda x, b, o=objective: label_free_terms(o, x, b, rig, pano)[
            "photometric"])
        for scale, key in ((1.0, "truth"), (1.1, "nearer"), (1 / 1.1, "farther")):
            out[f"{key}@{margin:g}"] = float(np.mean([float(term(
                jnp.asarray(inv[i:i + 1] * scale),
                {"surrogates": jnp.asarray(arrays["surrogates"][i:i + 1]),
                 "masks": jnp.asarray(arrays["masks"][i:i + 1])})) for i in range(count)]))
    return out


def score(work: Path, data: Path, label: str, model_path, candidates: str | None) -> dict:
    """Held-out metrics of a model (``candidates`` list spec) or of RTSS (``model_path``
    None), cached in the work folder by the model's hash (weights and configuration)."""
    n = len(dataset_seeds(data))
    if model_path is None:
        return cached_evaluation(work, {"method": TEACHER, "data": str(data.name), "samples": n,
                                        "pano": list(PANO_HW)},
                                 lambda rig: rtss_predictor(rig, TEACHER, PANO_HW), data)
    return cached_evaluation(work, {"method": label, "model": model_id(model_path),
                                    "data": str(data.name), "samples": n,
                                    "candidates": candidates},
                             lambda rig: net_predictor(Path(model_path), rig, candidates), data)


def curves(runs: list, rows: dict, path: Path, title: str) -> None:
    """Per variant: the label-free loss per step (running mean) and the held-out MAE at each
    validation, beside the unadapted model's and the teacher's MAE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.4))
    for run in runs:
        colour = CURVE_COLOURS[run["name"]]
        recs = metrics_records(Path(run["run"]))
        steps = np.array([r["step"] for r in recs if "loss" in r])
        loss = np.array([r["loss"] for r in recs if "loss" in r])
        if len(loss):
            k = min(25, len(loss))
            a.plot(steps[k - 1:], np.convolve(loss, np.ones(k) / k, "valid"), color=colour,
                   label=run["name"])
        vals = [r for r in recs if r.get("split") == "val"]
        if vals:
            b.plot([v["step"] for v in vals], [v["mae"] for v in vals], "o-", color=colour,
                   label=run["name"])
    # The trainer logs the gijax metric set, so the reference lines use the same definition
    # (the table reports the paper's).
    b.axhline(rows["before"]["mae_gijax"], color="k", ls="--", lw=0.8,
              label="before (training list)")
    b.axhline(rows[TEACHER]["mae_gijax"], color="tab:red", ls=":", lw=1.0, label=TEACHER)
    a.set_yscale("log")      # the teacher term makes one loss ~50x the other
    a.set_xlabel("step")
    a.set_ylabel("label-free loss (running mean)")
    a.legend(fontsize=7)
    b.set_xlabel("step")
    b.set_ylabel("held-out MAE, gijax metric (1/m)")
    b.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_png(fig, path, dpi=100)
    plt.close(fig)


def table(rows: dict, labels: dict) -> str:
    body = [[labels[k], fmt(r["mae"]), fmt(r["rmse"]), fmt(r["bad_0.1"], 3),
             fmt(r.get("coverage"), 3)] for k, r in rows.items()]
    return markdown_grid(["method (held-out scenes of the ring)", "MAE (1/m)", "RMSE",
                          "bad 0.1", "coverage"], body)


def comparisons(rows: dict) -> list:
    """(text, paired difference, claim holds) for each claim."""
    out = []
    before = rows["before"]["mae_per_sample"]
    for name in VARIANTS:
        if name not in rows:
            continue
        p = paired_difference(rows[name]["mae_per_sample"], before)
        out.append((f"{name} vs before", p, bool(rows[name]["mae"] < rows["before"]["mae"])))
    if "occlusion" in rows and "photometric" in rows:
        p = paired_difference(rows["occlusion"]["mae_per_sample"],
                              rows["photometric"]["mae_per_sample"])
        out.append(("occlusion vs photometric", p, bool(rows["occlusion"]["mae"]
                                                        < rows["photometric"]["mae"])))
    if "teacher" in rows:
        p = paired_difference(rows["teacher"]["mae_per_sample"], rows[TEACHER]["mae_per_sample"])
        out.append((f"teacher vs {TEACHER}", p, bool(rows["teacher"]["mae"]
                                                     < rows[TEACHER]["mae"])))
    return out


def main(argv=None) -> int:
    parser = script_parser(__doc__)
    add_common_arguments(parser, NAME, SCALES, seed=False,
                         scale_help="smoke: pipeline check (a few minutes); cpu: the reported "
                                    "figures (14 minutes on 2 cores beside a background "
                                    "training; resumable, and a rerun reuses the data, runs "
                                    "and evaluations)",
                         work_help="work folder for data, adaptation runs and cached evaluations "
                                   "(default experiments/out/work_<scale>)")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS),
                        help="which adaptations to run (default both)")
    parser.add_argument("--model", default=None, metavar="PATH|NAME",
                        help="the model adapted, as gijax adapt's --ckpt takes it (default the "
                             "demo's default bundled model)")
    args = parser.parse_args(argv)
    cfg = SCALES[args.scale]
    work, out, results = resolve_paths(args, NAME)
    started = time.perf_counter()
    from gijax.demo import DEFAULT_MODEL

    model = args.model or DEFAULT_MODEL
    data = [ensure_data(work, cfg, role) for role in ("frames", "test")]
    frames, test = Path(data[0]["path"]), Path(data[1]["path"])
    from gijax.store import resolve_model_path

    bundle = resolve_model_path(model)
    bundle_id = model_id(bundle)
    labels = {"before": f"{model} before (training list)",
              "before-spacing": f"{model} before (list recomputed for the ring: spacing)",
              TEACHER: f"{TEACHER} (classical; the teacher)"}
    rows = {"before": score(work, test, model, bundle, "train"),
            "before-spacing": score(work, test, model, bundle, "spacing"),
            TEACHER: score(work, test, TEACHER, None, None)}
    runs = []
    for name in args.variants:
        run = adapt(work, cfg, model, bundle_id, name, frames, test)
        runs.append(run)
        rows[name] = score(work, test, f"{model}-adapted-{name}", run["bundle"], "train")
        labels[name] = run["label"]
    for k, r in rows.items():
        log(f"  {labels[k]}: MAE {r['mae']:.4f}")
    claims = comparisons(rows)
    at_truth = objective_at_truth(model, frames, min(16, cfg["frames"]))
    from gijax.data import DatasetReader

    maps = out.with_name(out.name + "_maps.png")
    save_figure(maps, DatasetReader(test)[0],
                [(labels[k], r["first_prediction"]) for k, r in rows.items()],
                f"{RING}, first held-out scene ({args.scale} scale)")
    curve = out.with_name(out.name + "_curves.png")
    if runs:
        curves(runs, rows, curve, f"label-free adaptation of {model} to {RING} "
                                  f"({args.scale} scale; held-out MAE never used to choose)")
    meta = {"command": command_line(f"{NAME}.py", argv if argv is not None else sys.argv[1:]),
            "scale": args.scale, "config": cfg, "model": model,
            "model_weights": weights_id(bundle), "model_id": bundle_id, "rig": RING,
            "data": data, "adaptations": runs,
            "git_revision": revision(), "machine": machine_info(),
            "seconds": time.perf_counter() - started}
    strip = ("first_prediction",)
    write_json(out.with_suffix(".json"), {
        "meta": meta, "rows": {k: {f: v for f, v in r.items() if f not in strip}
                               for k, r in rows.items()},
        "claims": [{"comparison": t, "paired": p, "holds": h} for t, p, h in claims],
        "objective_at_truth": at_truth})
    claim_lines = [f"- {t}: {'holds' if h else 'does not hold'} (mean MAE); "
                   f"{paired_text(p)}" for t, p, h in claims]
    md = [f"# Label-free network adaptation ({args.scale})", "",
          f"Command `{meta['command']}` at git {meta['git_revision'][:12]}, "
          f"{meta['machine']['platform']}, {meta['machine']['cpu_count']} CPUs, "
          f"{meta['seconds']:.0f} s in all ({cfg['summary']}). The bundled {model} (weights "
          f"{meta['model_weights']}) adapted to {RING}, a 5-camera rig outside its training "
          f"mixture, on unlabeled frames (seed {SEEDS['frames']}); scored on held-out scenes "
          f"(seed {SEEDS['test']}) whose labels never reach a loss or choose a checkpoint.",
          "", table(rows, labels), "",
          "Scene by scene (paired bootstrap of per-scene MAE differences, 10,000 "
          "resamplings):", "", *claim_lines, "",
          f"The photometric term at the true distances of the first {at_truth['frames']} "
          "frames (labels read to score the objective only), and at the truth 10 % nearer / "
          "farther: every camera compared "
          + ", ".join(f"{at_truth[f'{k}@0']:.4f}" for k in ("truth", "nearer", "farther"))
          + f"; occlusion-aware (margin {OCCLUSION_MARGIN:g}) "
          + ", ".join(f"{at_truth[f'{k}@{OCCLUSION_MARGIN:g}']:.4f}"
                      for k in ("truth", "nearer", "farther")) + ".", "",
          *([f"This invocation reused runs of earlier ones (keyed by the weights; one "
             f"adapted with another objective is refused): "
             + "; ".join(f"{r['name']} (started at git "
                         + ", ".join(g[:12] + (" with uncommitted files" if g.endswith("+dirty")
                                               else "") for g in r["made_at"]) + ")"
                         for r in runs if r["reused"]) + ".", ""]
            if any(r["reused"] for r in runs) else []),
          "Commands: " + "; ".join(f"`{d['command']}`" for d in data)
          + "".join(f"; `{r['command']}`" for r in runs), "",
          f"![maps]({maps.name})", "", f"![curves]({curve.name})" if runs else "", ""]
    write_text(out.with_suffix(".md"), "\n".join(md))
    print("\n".join(md))
    if results is not None:
        publish_section(results, SECTION, "\n".join(md[2:]), [maps, curve])
    log(f"wrote {out.with_suffix('.md')}, {out.with_suffix('.json')}, {maps}"
        + (f", {curve}" if runs else ""))
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    raise SystemExit(main())
