"""``gijax models``: the trained models shipped with gijax, usable by name with ``--ckpt``."""

from __future__ import annotations

import json

HELP = "list the bundled trained models (usable by name: --ckpt NAME)"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "models", help=HELP,
        description=(
            "List the inference bundles shipped inside gijax (gijax/assets): name, preset (and "
            "the network settings in which a bundle departs from it), "
            "parameter count, what each was trained on, how it compares with classical stereo on "
            "held-out scenes and where it is expected to fail (from its PROVENANCE.json). The model "
            "option of predict, eval, export and demo ('gijax predict --ckpt NAME') accepts "
            "such a name as well as a path; a path that exists wins."))
    p.add_argument("--json", action="store_true", help="print one JSON list instead of text")
    p.set_defaults(func=run)


def run(args) -> int:
    from gijax.store import bundled_names, describe_bundled

    models = [describe_bundled(name) for name in bundled_names()]
    if args.json:
        print(json.dumps([{"name": m.name, "preset": m.preset,
                           "changed_from_preset": {k: list(v) if isinstance(v, tuple) else v
                                                   for k, v in m.changed.items()},
                           "parameters": m.parameters,
                           "trained_on": m.trained_on, "compared": m.compared,
                           "limitations": m.limitations,
                           "path": str(m.path),
                           "candidates": m.candidates} for m in models], indent=2))
        return 0
    if not models:
        print("no bundled models in this installation")
        return 0
    width = max(len(m.name) for m in models)
    print(f"{'name':<{width}}  {'preset':<14}{'parameters':>12}  trained on")
    for m in models:
        print(f"{m.name:<{width}}  {m.preset:<14}{m.parameters:>12,}  {m.trained_on}")
    for m in models:
        if m.changed:
            print(f"{m.name}: the {m.preset} network with " + ", ".join(
                f"{k}={'x'.join(map(str, v)) if isinstance(v, tuple) else v}"
                for k, v in m.changed.items()))
        print(f"{m.name}: {m.compared}")
        print(f"{m.name}: expected to fail on {m.limitations}")
    print(f"use one with --ckpt NAME, e.g. gijax predict --ckpt {models[0].name} ...")
    return 0
