"""The demo on fixed scene seeds: is the bundled model ahead of classical stereo on both rigs?

``gijax demo`` draws fresh scenes on each run, so one run is one draw. This script runs it as a
user types it, once per fixed seed (1-5 at the cpu scale, each with the demo's default of 3
scenes per rig), and tabulates, per seed and rig, the learned model's best candidate list and
RS-E32 (mean MAE over the seed's scenes, in 1/m as the paper defines it, and how many scenes
each wins). Target: the learned model ahead of RS-E32 on mean MAE on both rigs for every seed.

Each seed's demo folder is kept under ``<work>/demo_seeds/<weights id>/seed-<S>`` and reused
when its ``demo.json`` names the same model and source revision (a new bundle has new
weights, hence new folders).
Writes ``<out>.md``, ``<out>.json`` and, for ``--scale cpu``, the ``demo-seeds`` section of
``experiments/RESULTS.md``.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.arguments import (add_common_arguments, resolve_paths,  # noqa: E402
                                   script_parser)
from experiments.evaluation import model_id, weights_id  # noqa: E402
from experiments.provenance import command_line, revision  # noqa: E402
from experiments.reporting import (fmt, log, publish_section, read_json,  # noqa: E402
                                   write_json, write_text)
from experiments.workfolder import gijax_command  # noqa: E402
from gijax.bench.machine import machine_info  # noqa: E402
from gijax.bench.report import markdown_grid  # noqa: E402

NAME = "demo_seeds"
SECTION = "demo-seeds"
BASELINE = "RS-E32"
# Seeds fixed before any result was seen; scenes per rig as the demo's default.
SCALES = {"smoke": {"seeds": (1,), "scenes": 1},
          "cpu": {"seeds": (1, 2, 3, 4, 5), "scenes": 3}}


def short_revision(code: str) -> str:
    commit, _, dirty = code.partition("+")
    return commit[:12] + (f"+{dirty}" if dirty else "")


def demo_argv(seed: int, scenes: int, model: str, out: Path) -> list:
    return ["demo", "--seed", str(seed), "--scenes", str(scenes), "--ckpt", model,
            "--baseline", BASELINE, "--out", str(out), "--quiet"]


def ensure_demo(folder: Path, seed: int, scenes: int, model: str, code: str) -> dict:
    """The demo's ``demo.json`` for ``seed``, run (as a subprocess, the command a user types)
    unless the folder already holds a complete one for the same model, scene count and source
    revision ``code`` (a changed demo is run again)."""
    doc = read_json(folder / "demo.json")
    if (doc and doc.get("model") == model and doc.get("scenes_per_rig") == scenes
            and doc.get("git_revision") == code):
        log(f"seed {seed}: reusing {folder}")
        return doc
    argv = demo_argv(seed, scenes, model, folder)
    log(f"seed {seed}: {gijax_command(argv)}")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gijax", *argv], check=True,
                   stdout=subprocess.DEVNULL)
    doc = read_json(folder / "demo.json")
    if doc is None:
        raise RuntimeError(f"gijax demo wrote no readable {folder / 'demo.json'}")
    doc["seconds"] = time.perf_counter() - t0
    doc["git_revision"] = code
    write_json(folder / "demo.json", doc)
    return doc


def seed_rows(seed: int, doc: dict) -> list:
    """One row per rig: the demo's own verdict (the learned model's best list by mean MAE
    against the baseline, scenes won), with the seed."""
    from gijax.demo import rig_verdicts

    return [{"seed": seed, "rig": rig, **v}
            for rig, v in rig_verdicts(doc["table"], BASELINE).items()]


def main(argv=None) -> int:
    parser = script_parser(__doc__)
    add_common_arguments(parser, NAME, SCALES, seed=False,
                         scale_help="smoke: one seed, one scene per rig (a minute or two); "
                                    "cpu: the reported figures (seeds 1-5, 3 scenes per rig, "
                                    "about 10 minutes on 2 cores)",
                         work_help="work folder for the demo folders (default "
                                   "experiments/out/work_<scale>)")
    parser.add_argument("--model", default=None, metavar="PATH|NAME",
                        help="the model, as the demo's --ckpt takes it (default the demo's "
                             "default bundled model)")
    args = parser.parse_args(argv)
    cfg = SCALES[args.scale]
    work, out, results = resolve_paths(args, NAME)
    from gijax.demo import DEFAULT_MODEL
    from gijax.store import resolve_model_path

    model = args.model or DEFAULT_MODEL
    wid = weights_id(resolve_model_path(model))
    # The runs are kept by the model as it predicts (weights and configuration).
    mid = model_id(resolve_model_path(model))
    started, code = time.perf_counter(), revision()
    rows, commands = [], []
    for seed in cfg["seeds"]:
        folder = work / NAME / mid / f"seed-{seed}"
        commands.append(gijax_command(demo_argv(seed, cfg["scenes"], model, folder)))
        rows.extend(seed_rows(seed, ensure_demo(folder, seed, cfg["scenes"], model, code)))
    met = all(r["ahead"] for r in rows)
    ahead = sum(r["ahead"] for r in rows)
    target = (f"**{'MET' if met else 'MISSED'}**: the learned model ahead of {BASELINE} on mean "
              f"MAE on both rigs for each of {len(cfg['seeds'])} fixed seeds ({ahead} of "
              f"{len(rows)} rig-seeds ahead)")
    grid = markdown_grid(
        ["seed", "rig", "learned (best list)", "MAE", f"{BASELINE} MAE", "scenes won",
         "ahead"],
        [[str(r["seed"]), r["rig"], r["method"], fmt(r["mae"]), fmt(r["baseline_mae"]),
          f"{r['scenes_won']}/{r['scenes']}", "yes" if r["ahead"] else "no"] for r in rows])
    meta = {"command": command_line(f"{NAME}.py", argv if argv is not None else sys.argv[1:]),
            "scale": args.scale, "config": cfg, "model": model, "model_weights": wid,
            "model_id": mid,
            "demo_commands": commands, "git_revision": code, "machine": machine_info(),
            "seconds": time.perf_counter() - started}
    write_json(out.with_suffix(".json"), {"meta": meta, "rows": rows, "target_met": met})
    body = "\n\n".join([
        f"Command `{meta['command']}` at git {short_revision(code)}, {cfg['scenes']} scene(s) per rig and "
        f"seed; model `{model}` (weights {wid}; with its configuration, which says how it reads "
        f"them, model {mid}). Each seed is one `gijax demo` run as typed "
        f"(`{commands[0]}`, then the same with the next seed); MAE in 1/m, the paper's "
        f"definitions, the mean over the seed's scenes.", grid, f"- {target}"])
    write_text(out.with_suffix(".md"), f"# The demo on fixed seeds\n\n{body}\n")
    log(target.replace("**", ""))
    if results is not None:
        publish_section(results, SECTION, body, [])
    return 0


if __name__ == "__main__":
    sys.exit(main())
