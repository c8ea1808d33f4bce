"""JSON and Markdown output of benchmark results (written atomically: temp name, then rename)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Callable, Sequence, Union

import numpy as np

from gijax.io.paths import write_json_atomic, write_text_atomic

# A column: (header, key) or (header, key, format spec or callable value -> str).
Column = Union[tuple[str, str], tuple[str, str, Union[str, Callable]]]


def _plain(obj):
    """numpy scalars and arrays -> Python numbers and lists (for ``json``)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None  # JSON has no NaN / inf
    return obj


def write_json(path: str | os.PathLike, obj) -> Path:
    """Write ``obj`` as indented JSON (numpy values converted, non-finite floats as null)."""
    return write_json_atomic(path, _plain(obj))


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text``, ending in a newline."""
    return write_text_atomic(path, text if text.endswith("\n") else text + "\n")


def format_value(value, spec: Union[str, Callable, None] = None) -> str:
    """One table cell: '' for None, ``spec`` applied to numbers, str otherwise."""
    if value is None:
        return ""
    if callable(spec):
        return spec(value)
    if isinstance(value, float) and not math.isfinite(value):
        return ""
    if spec and isinstance(value, (int, float, np.number)) and not isinstance(value, bool):
        return format(value, spec)
    return str(value)


def markdown_grid(header: Sequence[str], rows: Sequence[Sequence[str]],
                  numeric: Sequence[bool] | None = None) -> str:
    """A GitHub Markdown table of ready-made cells: ``header`` and one list of strings per row;
    columns marked in ``numeric`` are right-aligned. A '|' inside a cell is escaped."""
    numeric = [False] * len(header) if numeric is None else list(numeric)
    if not header or len(numeric) != len(header):
        raise ValueError(f"markdown_grid needs a header and one alignment per column; found "
                         f"{len(header)} headers and {len(numeric)} alignments")
    lines = ["| " + " | ".join(header) + " |",
             "| " + " | ".join("---:" if n else "---" for n in numeric) + " |"]
    for row in rows:
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |")
    return "\n".join(lines)


def markdown_table(rows: Sequence[dict], columns: Sequence[Column]) -> str:
    """A GitHub Markdown table: one line per row, cells ``row[key]`` formatted per column
    (a missing key is an empty cell); numbers are right-aligned."""
    if not columns:
        raise ValueError("markdown_table needs at least one column")
    numeric = [any(isinstance(r.get(c[1]), (int, float, np.number))
                   and not isinstance(r.get(c[1]), bool) for r in rows) for c in columns]
    cells = [[format_value(r.get(c[1]), c[2] if len(c) > 2 else None) for c in columns]
             for r in rows]
    return markdown_grid([c[0] for c in columns], cells, numeric)


def text_table(rows: Sequence[dict], columns: Sequence[Column]) -> str:
    """The same table in fixed-width columns, for the terminal."""
    heads = [c[0] for c in columns]
    cells = [[format_value(r.get(c[1]), c[2] if len(c) > 2 else None) for c in columns]
             for r in rows]
    widths = [max([len(h)] + [len(row[i]) for row in cells]) for i, h in enumerate(heads)]
    out = ["  ".join(h.rjust(w) for h, w in zip(heads, widths)),
           "  ".join("-" * w for w in widths)]
    out += ["  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join(out)
