"""The command line shared by the experiment scripts: ``--scale``, ``--work``, ``--out``,
``--results`` (and ``--seed`` for the scripts that train from a seed)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from experiments.scales import SCALES

EXPERIMENTS = Path(__file__).resolve().parent


def script_parser(doc: str):
    """A script's parser: the first line of its docstring as the description, the rest as the
    epilog of ``--help``."""
    import argparse

    return argparse.ArgumentParser(description=doc.splitlines()[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter,
                                   epilog="\n".join(doc.splitlines()[2:]))


def parse_script_args(doc: str, name: str, argv: list):
    """The command line shared by the table scripts -> (args, scale, work, out, results)."""
    parser = script_parser(doc)
    add_common_arguments(parser, name)
    args = parser.parse_args(argv)
    return (args, SCALES[args.scale], *resolve_paths(args, name))


def add_common_arguments(parser, default_name: str, scales=SCALES,
                         scale_help: str = "smoke: pipeline check (about a minute); cpu: the "
                                           "reported figures (hours on 2 cores, resumable); "
                                           "paper: the paper's sizes (GPUs)",
                         work_help: str = "shared work folder for data, runs and cached "
                                          "evaluations (default experiments/out/work_<scale>)",
                         seed: bool = True) -> None:
    """``--scale`` (one of ``scales``), ``--work``, ``--out``, ``--results`` and, with
    ``seed``, ``--seed``."""
    parser.add_argument("--scale", choices=list(scales), default="smoke", help=scale_help)
    parser.add_argument("--work", default=None, help=work_help)
    parser.add_argument("--out", default=None,
                        help=f"output stem (default experiments/results/{default_name}_cpu for "
                             f"--scale cpu, else experiments/out/{default_name}_<scale>)")
    if seed:
        parser.add_argument("--seed", type=int, default=0, help="training seed (initialisation "
                                                                "and data order)")
    parser.add_argument("--results", default=None,
                        help="Markdown file whose section to update (default "
                             "experiments/RESULTS.md for --scale cpu, none otherwise); "
                             "'none' disables")


def resolve_paths(args, name: str) -> tuple[Path, Path, Optional[Path]]:
    work = Path(args.work) if args.work else EXPERIMENTS / "out" / f"work_{args.scale}"
    if args.out:
        out = Path(args.out)
    elif args.scale == "cpu":
        out = EXPERIMENTS / "results" / f"{name}_cpu"
    else:
        out = EXPERIMENTS / "out" / f"{name}_{args.scale}"
    if args.results == "none":
        results = None
    elif args.results:
        results = Path(args.results)
    else:
        results = EXPERIMENTS / "RESULTS.md" if args.scale == "cpu" else None
    return work, out, results
