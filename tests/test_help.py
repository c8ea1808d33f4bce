"""Every ``gijax ... --help``: each option explained, defaults printed once, no option named that
the command lacks, built-in rig lists the library's (parser only: no JAX compile)."""

from __future__ import annotations

import argparse
import re

import pytest

from gijax.cli import build_parser, main
from gijax.geometry.layouts import BUILTIN_LAYOUTS

OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
# A quoted command line or an example line names another command's options ('gijax render --rig R').
OTHER_COMMAND = re.compile(r"'gijax [^']*'|^\s*gijax .*$", re.MULTILINE)
# "default" as a word, not a quoted choice named 'default'.
DEFAULT_WORD = re.compile(r"(?<!')\bdefault\b(?!')", re.IGNORECASE)
RIG_NAME = re.compile(r"\bpaper-[a-z0-9-]*[a-z0-9]")


def _commands(parser, path=()):
    """(command path, parser) for the top level and every subcommand, depth first."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


COMMANDS = list(_commands(build_parser()))


def _options(parser):
    return [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def _expanded_help(parser, action) -> str:
    """An option's help as ``--help`` prints it (defaults added by the formatter, %-expanded)."""
    return parser._get_formatter()._expand_help(action) if action.help else ""


def _problems(path, parser) -> list[str]:
    name = " ".join(("gijax", *path))
    have = {s for a in parser._actions for s in a.option_strings}
    problems = []
    texts = [("description", parser.description or "")]
    for action in _options(parser):
        flag = "/".join(action.option_strings) or action.dest
        text = _expanded_help(parser, action)
        if not text.strip():
            problems.append(f"{name} {flag}: no help")
            continue
        texts.append((flag, text))
        if len(DEFAULT_WORD.findall(text)) > 1:
            problems.append(f"{name} {flag}: default stated twice: {text!r}")
        if action.required and "None" in text:
            problems.append(f"{name} {flag}: required but its help shows None: {text!r}")
    for where, text in texts:
        for option in set(OPTION.findall(OTHER_COMMAND.sub("", text))) - have:
            problems.append(f"{name} ({where}): mentions {option}, which it does not have")
        names = set(RIG_NAME.findall(text))
        if "built-in" in text and names and names != set(BUILTIN_LAYOUTS):
            problems.append(f"{name} ({where}): built-in rigs {sorted(names)}, the library "
                            f"has {sorted(BUILTIN_LAYOUTS)}")
    return problems


def test_the_walk_reaches_every_command():
    names = {" ".join(p) for p, _ in COMMANDS}
    # Nested actions are reached too (a broken walk would check nothing).
    assert {"train", "eval", "predict", "render", "rig show", "rig refine", "trt build",
            "trt run", "data check"} <= names
    assert len(COMMANDS) > 20


@pytest.mark.parametrize("path,parser", COMMANDS, ids=[" ".join(p) or "gijax"
                                                      for p, _ in COMMANDS])
def test_help_explains_every_option(path, parser):
    assert _problems(path, parser) == []
    parser.format_help()        # formats (a bad % in a help text raises here)


def test_the_checks_catch_each_defect():
    p = argparse.ArgumentParser(description="see --nowhere; 'gijax render --pano 8x32' is fine",
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--bare")
    p.add_argument("--twice", default=3, help="steps (default 3)")
    p.add_argument("--needed", required=True, help="a path")
    p.add_argument("--rig", help="built-in rig name (paper-train, paper-test1)")
    found = "\n".join(_problems(("x",), p))
    assert "--bare: no help" in found
    assert "--twice: default stated twice" in found
    assert "--needed: required but its help shows None" in found
    assert "mentions --nowhere" in found and "--pano" not in found
    assert "built-in rigs ['paper-test1', 'paper-train']" in found


def test_one_vocabulary(capsys):
    parser = build_parser()
    sub = {p: q for p, q in COMMANDS}
    rig_helps = {_expanded_help(q, a).split(" (default")[0] for p, q in COMMANDS
                 for a in q._actions if "--rig" in a.option_strings}
    assert len(rig_helps) == 1              # one text, whatever each command's default
    # (gijax design's --candidates is a count, not a list: its own meaning.)
    metavars = {a.metavar for p, q in COMMANDS for a in q._actions
                if "--candidates" in a.option_strings and a.type is not int}
    assert metavars == {"train|spacing|rig|ev|FILE"} and "train" in dict(
        (a.dest, a) for a in sub[("train",)]._actions)["candidates"].metavar
    assert parser.parse_args(["eval", "--data", "d", "--method", "net"]).method == "learned"
    assert parser.parse_args(["predict", "--rig", "r", "--images", "a", "--out", "o",
                              "--method", "learned"]).method == "learned"
    base = ["render", "--rig", "r", "--samples", "1", "--out", "o"]
    assert parser.parse_args([*base, "--image-size", "8x16"]).image_size == (8, 16)
    assert parser.parse_args([*base, "--size", "16x8"]).size == (8, 16)     # older WxH form
    assert parser.parse_args([*base, "--pano", "32x8"]).pano == (8, 32)
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--image-size", "8by16"])
    assert "--image-size '8by16': expected HxW" in capsys.readouterr().err


def test_misspelt_candidate_keyword_lists_the_keywords(tmp_path, capsys):
    # A rig-free spec error, reported before any model or data is read.
    from gijax.candidates.spec import resolve_candidates

    with pytest.raises(FileNotFoundError) as err:
        resolve_candidates("spcing", None, 16)
    assert str(err.value) == ("--candidates spcing: not one of the keywords train, spacing, "
                              "rig, ev, and no candidate file spcing exists")


def test_mixed_image_sizes_name_the_file(tmp_path, capsys):
    import cv2
    import numpy as np

    a, b = tmp_path / "a.png", tmp_path / "b.png"
    cv2.imwrite(str(a), np.zeros((8, 16, 3), np.uint8))
    cv2.imwrite(str(b), np.zeros((8, 12, 3), np.uint8))
    rc = main(["predict", "--rig", "paper-test3", "--images", str(a), str(b), str(a), str(a),
               "--method", "rtss", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 1 and f"{b}: image is 8 x 12 but {a} is 8 x 16" in err
    assert not (tmp_path / "out").exists()


def test_every_option_of_the_experiment_and_benchmark_scripts_is_explained():
    """The scripts under experiments/ and benchmarks/ build their parsers inside main(), so the
    check reads their source: every ``add_argument`` call has a ``help`` (argparse.SUPPRESS for
    internal ones); a shared builder (``add_common_arguments``) is checked where it lives."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    missing = []
    for folder in ("experiments", "benchmarks"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                        and node.func.attr == "add_argument"
                        and not any(k.arg == "help" for k in node.keywords)):
                    name = next((a.value for a in node.args if isinstance(a, ast.Constant)), "?")
                    missing.append(f"{path.relative_to(root)}:{node.lineno} {name}")
    assert not missing, "options without a help text:\n" + "\n".join(missing)
