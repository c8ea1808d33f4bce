"""How much error the cost volume's cell size alone leaves: oracle predictions from the labels.

The CPU presets regress distance on a cost volume coarser than their output (``G16VV-cpu``:
16 x 64 cells under a 32 x 128 output, ``output_stride`` 2), so even a network that found
every cell's distance exactly could not draw what varies inside a cell. This script measures
that floor on the held-out scenes of the bundle's tables, from their labels alone (no model):

* ``cell mean, bilinear``: the label's inverse distance averaged over each cost-volume cell
  (usable pixels only), upsampled to the output bilinearly (half-pixel centres, as the
  network's regressor upsamples);
* ``cell mean, repeated``: the same averages, each repeated over its cell's pixels;
* ``nearest candidate``: the label at the output's resolution snapped to the nearest of the
  bundle's 16 candidates (what an exact arg-max would give without the soft-argmax).

Each is scored with the paper's metric (MAE of inverse distance in 1/m over the labels in the
candidate range, ``gijax.evaluate.metrics.paper_sample_metrics``), the same as the tables, and
shown beside the bundle's and RS-E32's MAE from the weight-averaging table's JSON.
The data are the tables' own held-out sets in the work folder, rendered by their recorded
commands when missing. Writes ``<out>.md``, ``<out>.json`` and, for ``--scale cpu``, the
``resolution-floor`` section of ``experiments/RESULTS.md``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.arguments import add_common_arguments, resolve_paths, script_parser  # noqa: E402
from experiments.provenance import command_line, revision  # noqa: E402
from experiments.reporting import fmt, log, publish_section, read_json, save_table  # noqa: E402
from experiments.scales import SCALES  # noqa: E402

NAME = "resolution_floor"
SECTION = "resolution-floor"
DESIGN = "G16VV-cpu-zncc"
SETS = ("paper-test1", "paper-test2", "paper-test3", "ring5-0.5m", "val")
ORACLES = ("cell mean, bilinear", "cell mean, repeated", "nearest candidate")


def oracle_maps(inv, usable, stride: int, candidates):
    """The three oracle predictions (H, W) of one label map ``inv`` (H, W) 1/m, from the
    pixels where ``usable``; ``stride`` output pixels per cost cell along each axis."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    h, w = inv.shape
    if h % stride or w % stride:
        raise ValueError(f"label map {h} x {w} is not a whole number of {stride} x {stride} cells")
    cells = (h // stride, stride, w // stride, stride)
    total = np.where(usable, inv, 0.0).reshape(cells).sum(axis=(1, 3))
    count = usable.reshape(cells).sum(axis=(1, 3))
    mean = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    inv_cand = 1.0 / np.asarray(candidates, np.float64)
    nearest = inv_cand[np.argmin(np.abs(inv[..., None] - inv_cand), axis=-1)]
    return {
        "cell mean, bilinear": np.asarray(jax.image.resize(jnp.asarray(mean), (h, w), "linear")),
        "cell mean, repeated": np.repeat(np.repeat(mean, stride, axis=0), stride, axis=1),
        "nearest candidate": nearest,
    }


def floor_of(path: Path, stride: int, candidates) -> dict:
    """Mean per-scene paper MAE of each oracle over the dataset at ``path``."""
    import jax.numpy as jnp
    import numpy as np

    from gijax.data import DatasetReader
    from gijax.evaluate.labels import clamped_inverse, label_mask
    from gijax.evaluate.metrics import paper_sample_metrics

    reader = DatasetReader(path)
    cand = jnp.asarray(candidates, jnp.float32)
    per_scene = {k: [] for k in ORACLES}
    for i in range(len(reader)):
        d = np.asarray(reader[i]["pano_distance"], np.float32)[None]
        ok = np.ones_like(d, bool)
        usable = np.asarray(label_mask(jnp.asarray(d), jnp.asarray(ok)))[0] > 0
        inv = np.asarray(clamped_inverse(jnp.asarray(d), cand), np.float64)[0]
        for name, pred in oracle_maps(inv, usable, stride, candidates).items():
            m = paper_sample_metrics(jnp.asarray(pred[None], jnp.float32), jnp.asarray(d),
                                     jnp.asarray(ok), cand)
            per_scene[name].append(float(m["mae"][0]))
    return {"scenes": len(reader), **{k: float(np.mean(v)) for k, v in per_scene.items()}}


def reported_mae() -> dict:
    """(set -> {'bundle', 'RS-E32'}) MAE of the bundle (its training list) and RS-E32 from the
    weight-averaging table's rows (``experiments/results/weight_average_cpu.json``, written by
    ``experiments/weight_average.py``); empty when that file is missing."""
    doc = read_json(Path(__file__).resolve().parent / "results" / "weight_average_cpu.json")
    out = {}
    for row in (doc or {}).get("rows", []):
        if row["model"] == "RS-E32":
            out.setdefault(row["test"], {})["RS-E32"] = float(row["mae"])
        elif row["model"] == "averaged" and row["list"] == "train":
            out.setdefault(row["test"], {})["bundle"] = float(row["mae"])
    return out


def main(argv=None) -> int:
    parser = script_parser(__doc__)
    add_common_arguments(parser, NAME, seed=False)
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS),
                        help="held-out sets to measure (default: all of them)")
    args = parser.parse_args(argv)
    scale = SCALES[args.scale]
    work, out, results = resolve_paths(args, NAME)
    t0 = time.time()
    command = command_line(Path(__file__).name, sys.argv[1:] if argv is None else argv)
    from experiments import learned_candidates as LC
    from experiments.workfolder import ensure_dataset
    from gijax.nn.presets import get_preset

    config = get_preset(DESIGN)
    bundle = Path(__file__).resolve().parents[1] / "gijax" / "assets" / DESIGN / "config.json"
    doc = read_json(bundle)
    if not doc or "candidates" not in doc:
        raise SystemExit(f"{bundle}: no 'candidates' list (the bundled model's config)")
    candidates = [float(c) for c in doc["candidates"]]
    rows = {}
    for name in args.sets:
        if name == "ring5-0.5m":
            rec = LC.ensure_extra_dataset(work, scale, name, LC.SIZES[scale.name].ring_test)
        else:
            rec = ensure_dataset(work, scale, name)
        log(f"{name}: {rec['samples']} scenes")
        rows[name] = floor_of(Path(rec["path"]), config.output_stride, candidates)
    reported = reported_mae()
    head = ["held-out set", "scenes", *ORACLES, "bundle (reported)", "RS-E32 (reported)",
            "0.75 x RS-E32"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, r in rows.items():
        rep = reported.get(name, {})
        rs = rep.get("RS-E32")
        cells = [name, str(r["scenes"]), *(fmt(r[k]) for k in ORACLES),
                 fmt(rep["bundle"]) if "bundle" in rep else "-", fmt(rs) if rs else "-",
                 fmt(0.75 * rs) if rs else "-"]
        lines.append("| " + " | ".join(cells) + " |")
    body = (f"Oracle predictions from the labels at the cost volume of `{DESIGN}` "
            f"({config.cost_hw[0]} x {config.cost_hw[1]} cells, {config.output_stride} x "
            f"{config.output_stride} output pixels each; the bundle's {len(candidates)} GI "
            "candidates), paper MAE in 1/m, mean over scenes:\n\n" + "\n".join(lines) +
            f"\n\n- command: `{command}`\n- git revision: {revision()}\n"
            f"- duration: {time.time() - t0:.0f} s\n")
    doc = {"design": DESIGN, "cost_hw": list(config.cost_hw),
           "output_stride": config.output_stride, "candidates": candidates, "rows": rows,
           "reported": reported, "command": command, "git_revision": revision()}
    save_table(out, "Resolution floor of the cost volume", body, doc)
    print(body)
    if results is not None:
        publish_section(results, SECTION, body, [])
    return 0


if __name__ == "__main__":
    sys.exit(main())
