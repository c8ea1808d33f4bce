"""Weight averaging of the long training's checkpoints, evaluated and published as a bundle.

The mean of several committed resume packs of one run, evaluated as the bundle is and, with
``--publish``, written as a bundle.

At the long training's still-high learning rate, the validation MAE of single checkpoints
wanders by +-5 % from one thousand steps to the next while the curve is flat (0.0205-0.0221
from step 15000 on): the run moves around a basin rather than down into it. The mean of the
late checkpoints (stochastic weight averaging, Izmailov et al. 2018) lies nearer the basin's
middle. Each pack is read from the git revision that committed it (``--packs REV ...``; the
packs README lists them), its state file checked against the SHA-256 in its ``pack.json``; the
network variables are averaged (:func:`gijax.train.bundle.save_averaged_bundle`: parameters and
BatchNorm statistics alike, the statistics not recomputed) and evaluated beside the previous
bundle and RS-E32 on the bundle's held-out test sets and targets
(``experiments/bundle_model.py``'s evaluation, cached in the work folder).

    python experiments/weight_average.py --scale cpu --work /work/gijax-work
    python experiments/weight_average.py --scale cpu --work /work/gijax-work \\
        --previous <a copy of the bundle> --publish gijax/assets/G16VV-cpu-zncc
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments import bundle_model  # noqa: E402
from experiments.arguments import add_common_arguments, resolve_paths, script_parser  # noqa: E402
from experiments.provenance import provenance_markdown, provenance_record  # noqa: E402
from experiments.reporting import (check_results_section, log, publish_section,  # noqa: E402
                                   save_table)
from experiments.scales import SCALES  # noqa: E402

NAME = "weight_average"
ROOT = Path(__file__).resolve().parents[1]
DESIGN = "G16VV-cpu-zncc"
# The revisions that committed the long training's packs at steps 16000-21000 (packs README).
DEFAULT_PACKS = ("166bb8c", "3167dc5", "8a6431e", "4834eb1", "d71ee18", "3408a3a")
BUNDLE = ROOT / "gijax" / "assets" / DESIGN


def extract_pack(revision: str, folder: str, dest: Path):
    """The resume pack that ``revision`` committed in ``folder`` (a path in the repository),
    copied to ``dest`` and read back (its state file checked against its SHA-256)."""
    import json

    from gijax.store.packs import PACK_FILE, read_pack

    def show(name: str) -> bytes:
        r = subprocess.run(["git", "show", f"{revision}:{folder}/{name}"], cwd=ROOT,
                           capture_output=True)
        if r.returncode != 0:
            raise ValueError(f"revision {revision}: no {folder}/{name} "
                             f"({r.stderr.decode(errors='replace').strip()})")
        return r.stdout

    dest.mkdir(parents=True)
    doc = show(PACK_FILE)
    (dest / PACK_FILE).write_bytes(doc)
    (dest / "metrics.jsonl").write_bytes(show("metrics.jsonl"))
    state = json.loads(doc)["state_file"]
    (dest / Path(state).name).write_bytes(show(state))
    return read_pack(dest)


def bundle_provenance(previous: Path, log_folder: Path, recipe, packs_doc: list, prov: dict,
                      targets: list) -> dict:
    """The averaged bundle's PROVENANCE.json: the previous bundle's record of the same run (data,
    commands, limitations), with what these weights are, the run's pieces and validations up
    to the newest pack, and this script's command, revision and targets."""
    from gijax.store.bundles import read_provenance

    from experiments.workfolder import metrics_records

    doc = dict(read_provenance(previous))
    records = metrics_records(log_folder)
    steps = [d["step"] for d in packs_doc]
    kept = (f"the mean of the network variables of the checkpoints at steps "
            f"{', '.join(str(s) for s in steps)} (BatchNorm statistics averaged too)")
    trained = max(int(r["step"]) for r in records if "loss" in r)
    head = str(doc.get("trained_on", "")).split("; training:")[0]
    doc.update({
        "trained_on": (f"{head}; training: {trained} steps of {recipe.batch} ({kept}), "
                       f"augmentation {recipe.augment}, calibration errors up to "
                       f"{recipe.calibration_deg:g} deg, starting from random weights"),
        "checkpoint": kept, "averaged_packs": packs_doc,
        "made_by": prov["command"], "git_revision": prov["git_revision"],
        "runs": bundle_model.run_pieces(records),
        "validation": [r for r in records if r.get("split") == "val"],
        "targets": targets})
    return doc


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = script_parser(__doc__)
    add_common_arguments(parser, NAME, scales={"cpu": SCALES["cpu"]},
                         scale_help="cpu: the long training's packs (the only scale they "
                                    "exist at)", seed=False)
    parser.add_argument("--packs", nargs="+", default=list(DEFAULT_PACKS), metavar="REV",
                        help="git revisions whose committed long-training pack is averaged "
                             f"(default: steps 16000-21000, {' '.join(DEFAULT_PACKS)})")
    parser.add_argument("--previous", default=str(BUNDLE),
                        help="the bundle evaluated beside the average (default: the packaged "
                             f"{DESIGN}; copy it aside first when --publish replaces it)")
    parser.add_argument("--publish", default=None, metavar="DIR",
                        help="write the averaged bundle, its provenance and figures to DIR")
    args = parser.parse_args(argv)
    if args.publish and Path(args.publish).resolve() == Path(args.previous).resolve():
        parser.error("--publish would replace the --previous bundle it is compared with; "
                     "copy that bundle aside and name the copy as --previous")
    from gijax.train.bundle import save_averaged_bundle

    scale, recipe = SCALES[args.scale], bundle_model.LONG_RECIPES[args.scale]
    work, out, results = resolve_paths(args, NAME)
    if results is not None:
        check_results_section(results, NAME)
    started, durations = time.time(), {}
    t0 = time.perf_counter()
    data = bundle_model.prepare(work, scale, recipe)
    durations["data"] = time.perf_counter() - t0
    folder = f"experiments/packs/long-{DESIGN}"
    with tempfile.TemporaryDirectory(prefix="gijax-weight-average-") as tmp:
        tmp = Path(tmp)
        # Named by run and revision: the learning curve's title is its folder's name.
        packs = [extract_pack(rev, folder, tmp / f"long-{DESIGN}@{rev}") for rev in args.packs]
        steps = [p.step for p in packs]
        log(f"averaging the packs of steps {steps}")
        # The config travels through a copy: the bundle it comes from may be the one replaced.
        config = tmp / "config.json"
        shutil.copyfile(Path(args.previous) / "config.json", config)
        averaged = tmp / "averaged"             # evaluated from here; cached by its weights
        packs_doc = [{"revision": rev, "step": p.step, "state_file": p.meta["state_file"],
                      "state_sha256": p.meta["state_sha256"]}
                     for rev, p in zip(args.packs, packs)]
        save_averaged_bundle(packs, config, averaged, {"averaged_packs": packs_doc})
        t0 = time.perf_counter()
        models = {"averaged": averaged, "previous bundle": Path(args.previous)}
        rows, preds = bundle_model.evaluate(work, scale, models)
        # The training mixture's validation set, as the learning curve scores it (its MAE is
        # the 'MAE (gijax)' column: labels clamped to the candidate range, pixels pooled).
        rows += bundle_model.evaluate(work, scale, models, tests=("val",), lists=("train",))[0]
        durations["evaluation"] = time.perf_counter() - t0
        targets = bundle_model.check_targets(rows, "averaged")
        bundle_model.log_targets(targets)
        # The learning curve across every piece, from the newest pack's log.
        newest = max(packs, key=lambda p: p.step)
        val_mae = next(r["mae_gijax"] for r in rows
                       if r["test"] == "val" and r["model"] == "averaged")
        figures = bundle_model.write_figures(out, work, scale, preds, newest.folder,
                                             (min(steps), max(steps), val_mae))
        prov = provenance_record(f"{NAME}.py", argv, scale, 0, work, started, durations, data)
        prov["averaged_packs"] = packs_doc
        doc = {"table": NAME, "rows": rows, "targets": targets, "packs": packs_doc,
               "figures": {k: v.name for k, v in figures.items()}, "provenance": prov}
        md = "\n\n".join([
            f"{DESIGN}: the mean of the network variables of the long training's packs at steps "
            f"{', '.join(str(s) for s in steps)} (revisions {', '.join(args.packs)}), beside "
            f"the previous bundle and RS-E32 on the bundle's held-out scenes (inverse distance, "
            f"1/m, the paper's metric definitions; 'spacing' is the paper's recomputed list; "
            f"'val' is the training mixture's validation set, whose learning curve plots its "
            f"'MAE (gijax)').",
            bundle_model.table_markdown(rows), "## Targets",
            bundle_model.targets_markdown(targets),
            *(f"![{t}]({figures[t].name})" for t in bundle_model.TESTS),
            "## Provenance", provenance_markdown(prov)])
        save_table(out, "Weight averaging of the long training", md, doc)
        if results is not None:
            publish_section(results, NAME, md,
                            [figures[t] for t in bundle_model.TESTS])
        if args.publish:
            provenance = bundle_provenance(Path(args.previous), newest.folder, recipe,
                                           packs_doc, prov, targets)
            save_averaged_bundle(packs, config, Path(args.publish), provenance, figures={
                "learning_curve.png": figures["curve"],
                **{f"validation_{t}.png": figures[t] for t in bundle_model.TESTS}})
            log(f"wrote the bundle {args.publish}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
