"""Imports only point down the layer order; commands do not import each other; the experiments
and benchmarks use the library, not the command line.

Every module under ``gijax/`` is parsed with ``ast`` (nothing is imported) and each import it
makes, at module level or inside a function, is an edge from its unit to the target's unit. A
unit is a top-level module or package of ``gijax`` (``gijax.train.trainer`` belongs to
``train``). The layers, lowest first; a unit may import its own modules and units of lower
layers, never a unit of its own layer or a higher one:

==  =========================================  ==============================================
 0  gijax (the package root: ``__version__``)
 1  numerics, checks, random_streams           guarded elementary operations; the one message
                                               of a bad value; the named random streams
 2  geometry                                   cameras, rotations, rigs, panoramas, layouts
 3  io                                         rig and calibration files, locks, output paths
 4  candidates                                 EV / GI candidate lists and specs
 5  sampling                                   the bilinear sampler
 6  sweep                                      surrogate images, sweep grids and their pytrees
 7  nn                                         network modules and presets
 8  model                                      the whole network and its config-to-grid sizes
 9  render                                     procedural scenes and the ray caster
10  evaluate                                   usable labels, metrics, the prediction type
                                               and the evaluation loop
11  store, data, baseline, design, viz         trained models on disk, datasets (rendered
                                               with ``render``), the classical baseline,
                                               layout design, figures
12  calibrate                                  calibration refinement from unlabeled
                                               images (uses ``baseline`` to start)
13  train, export, predict                     training (writes run folders, reads them
                                               back through ``store``), ONNX / TensorRT,
                                               inference and the predictors
14  demo, bench                                the demo, the benchmark suite
15  cli                                        the ``gijax`` command
16  __main__                                   ``python -m gijax``
==  =========================================  ==============================================

A new top-level module fails here until it is given a layer. Inside ``gijax/cli`` a
``cmd_*.py`` module imports no other ``cmd_*.py`` (what two commands share lives in the library
or in a non-command helper such as ``gijax/cli/options.py``). Nothing under ``experiments/`` or
``benchmarks/`` imports ``gijax.cli`` (or ``gijax.__main__``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "gijax"

LAYERS = (
    ("gijax",),
    ("numerics", "host_memory", "checks", "random_streams"),
    ("geometry",),
    ("io",),
    ("candidates",),
    ("sampling",),
    ("sweep",),
    ("nn",),
    ("model",),
    ("render",),
    ("evaluate",),
    ("store", "data", "baseline", "design", "viz"),
    ("calibrate",),
    ("train", "export", "predict"),
    ("demo", "bench"),
    ("cli",),
    ("__main__",),
)
LEVEL = {unit: level for level, units in enumerate(LAYERS) for unit in units}
COMMAND_LINE = ("gijax.cli", "gijax.__main__")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_submodule(dotted: str) -> bool:
    """Whether ``gijax.a.b`` names a module or package (rather than a name inside one)."""
    rel = Path(*dotted.split(".")[1:]) if "." in dotted else Path()
    return (PACKAGE / rel).with_suffix(".py").is_file() or (PACKAGE / rel).is_dir()


def imports(path: Path, name: str) -> list[tuple[int, str]]:
    """``(line, imported module)`` of every import in a file, function-local ones included;
    ``from X import y`` yields ``X.y`` when that is a module, else ``X``; relative imports are
    resolved against the file's package; ``importlib.import_module('...')`` with a literal
    name counts too."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                dotted = f"{target}.{alias.name}"
                out.append((node.lineno, dotted if dotted.startswith("gijax.")
                            and _is_submodule(dotted) else target))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr == "import_module" and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            out.append((node.lineno, node.args[0].value))
    return list(dict.fromkeys(out))               # one entry per line and target


def unit_of(module: str) -> str | None:
    """The layer unit of a gijax module name, None for other packages."""
    parts = module.split(".")
    if parts[0] != "gijax":
        return None
    return parts[1] if len(parts) > 1 else "gijax"


def package_modules() -> list[tuple[Path, str]]:
    return [(p, module_name(p)) for p in sorted(PACKAGE.rglob("*.py"))]


def test_every_unit_has_a_layer():
    units = {unit_of(name) for _, name in package_modules()}
    missing = sorted(units - set(LEVEL))
    assert not missing, (f"gijax units without a layer: {missing}; add each to LAYERS in "
                         f"{Path(__file__).name} where its imports put it")


def test_imports_point_down_the_layers():
    problems = []
    for path, name in package_modules():
        src = unit_of(name)
        if src not in LEVEL:
            continue                      # reported by test_every_unit_has_a_layer
        for line, target in imports(path, name):
            dst = unit_of(target)
            if dst is None or dst == src:
                continue
            if dst not in LEVEL:
                problems.append(f"{path.relative_to(ROOT)}:{line} imports {target} (unit "
                                f"{dst!r} has no layer)")
            elif LEVEL[dst] >= LEVEL[src]:
                how = "a peer" if LEVEL[dst] == LEVEL[src] else "a higher layer"
                problems.append(f"{path.relative_to(ROOT)}:{line}: {src} (layer {LEVEL[src]}) "
                                f"imports {target}, {how} ({dst}, layer {LEVEL[dst]})")
    assert not problems, "imports against the layer order:\n" + "\n".join(problems)


def test_commands_do_not_import_each_other():
    problems = []
    for path, name in package_modules():
        if not (name.startswith("gijax.cli.cmd_") and name.count(".") == 2):
            continue
        for line, target in imports(path, name):
            parts = target.split(".")
            if (len(parts) >= 3 and parts[:2] == ["gijax", "cli"]
                    and parts[2].startswith("cmd_") and ".".join(parts[:3]) != name):
                problems.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not problems, ("command modules importing other commands (move what they share "
                          "into the library):\n" + "\n".join(problems))


def test_experiments_and_benchmarks_do_not_import_the_command_line():
    problems = []
    for folder in ("experiments", "benchmarks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for line, target in imports(path, module_name(path)):
                if any(target == c or target.startswith(c + ".") for c in COMMAND_LINE):
                    problems.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not problems, ("scripts importing the command line (call the library, or run "
                          "'gijax' as a subprocess):\n" + "\n".join(problems))


def test_the_checks_see_local_relative_and_package_imports(tmp_path):
    """The import reader on a file written for the purpose: function-local, relative,
    ``from gijax import <module>`` and ``importlib.import_module`` imports are all found."""
    text = ("import numpy\n"
            "from gijax import store, __version__\n"
            "from . import losses\n"
            "from ..cli import cmd_train\n"
            "def f():\n"
            "    import importlib\n"
            "    from gijax.cli.cmd_eval import run\n"
            "    return importlib.import_module('gijax.demo')\n")
    probe = tmp_path / "probe.py"
    probe.write_text(text)
    found = sorted(t for _, t in imports(probe, "gijax.train.probe"))
    assert found == ["gijax", "gijax.cli.cmd_eval", "gijax.cli.cmd_train", "gijax.demo",
                     "gijax.store", "gijax.train.losses", "importlib", "numpy"], found
    assert [unit_of(t) for t in found] == ["gijax", "cli", "cli", "demo", "store", "train",
                                           None, None]


def unit_graph() -> dict[str, set[str]]:
    """Each unit's directly imported units (the package root excluded)."""
    edges: dict[str, set[str]] = {}
    for path, name in package_modules():
        src = unit_of(name)
        for _, target in imports(path, name):
            dst = unit_of(target)
            if dst is not None and dst not in (src, "gijax"):
                edges.setdefault(src, set()).add(dst)
    return edges


def test_the_architecture_doc_shows_the_real_import_graph():
    """docs/architecture.md's "import graph" table lists, for every unit, exactly the units its
    modules import (so the documented graph is the code's, not a wish)."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    section = text.split("## The import graph", 1)[1].split("\n## ", 1)[0]
    documented = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 2 and cells[0].startswith("`"):
            deps = set() if cells[1] == "(none)" else {d.strip(" `") for d in cells[1].split(",")}
            documented[cells[0].strip("`")] = deps
    actual = unit_graph()
    want = {u: actual.get(u, set()) for units in LAYERS for u in units if u != "gijax"}
    wrong = {u: (sorted(documented.get(u, ())), sorted(want[u])) for u in want
             if documented.get(u) != want[u]}
    assert not wrong, ("docs/architecture.md import graph differs from the code "
                       "(unit: documented, actual): " + repr(wrong))
