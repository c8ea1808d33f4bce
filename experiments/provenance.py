"""Provenance of a table: the exact command, scale, seeds, datasets, source revision, machine and
durations, recorded in ``<out>.json`` and summarised in ``<out>.md``."""

from __future__ import annotations

import shlex
import time
from pathlib import Path

from experiments.scales import DATA_SEEDS, DATA_STYLE, Scale

ROOT = Path(__file__).resolve().parents[1]
# Files the scripts rewrite themselves: changing them does not make the source revision dirty
# (a long training rewrites its resume pack while other experiments run beside it).
OWN_OUTPUTS = ("experiments/results", "experiments/RESULTS.md", "experiments/packs")


def revision() -> str:
    """``HEAD`` commit, with ``+dirty`` when tracked files differ from it (the result files these
    scripts write themselves do not count); 'unknown' outside a git checkout."""
    from gijax.bench.machine import git_revision

    rev = git_revision(ROOT, ignore=OWN_OUTPUTS)
    return (rev["commit"] or "unknown") + ("+dirty" if rev["dirty"] else "")


def command_line(script: str, argv) -> str:
    return "python " + shlex.join([f"experiments/{script}", *argv])


def provenance_record(script: str, argv, scale: Scale, seed: int, work: Path, started: float,
                      durations: dict, data: list) -> dict:
    from gijax.bench.machine import machine_info
    from gijax.bench.memory import host_peak_rss_mib

    return {"command": command_line(script, argv), "scale": scale.name,
            "scale_summary": scale.summary, "seed": seed, "data_seeds": DATA_SEEDS,
            "data_style": DATA_STYLE, "datasets": data, "work": str(work),
            "git_revision": revision(), "machine": machine_info(),
            "started_unix": started, "finished_unix": time.time(),
            "durations_s": {**durations, "total": time.time() - started},
            "host_peak_rss_mb": host_peak_rss_mib()}


def provenance_markdown(prov: dict) -> str:
    m = prov["machine"]
    dur = ", ".join(f"{k} {v:.0f} s" for k, v in prov["durations_s"].items())
    data = "; ".join(f"{d['role']}: {d['rig']} x {d['samples']} (seed {d['seed']})"
                     for d in prov["datasets"])
    return "\n".join([
        f"- command: `{prov['command']}`",
        f"- scale: {prov['scale']} ({prov['scale_summary']})",
        f"- training seed: {prov['seed']}; data ({prov['data_style']} scenes): {data}",
        f"- git revision: {prov['git_revision']}",
        f"- machine: {m['platform']}, {m['cpu']} ({m['cpu_count']} CPUs), jax "
        f"{m['versions']['jax']}, device {m['backend']} {m['device']}",
        f"- durations: {dur}",
    ])
