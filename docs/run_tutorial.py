"""Run ``docs/tutorial.ipynb`` top to bottom without Jupyter, optionally storing its outputs.

    python docs/run_tutorial.py            # run it at its own sizes and write the outputs in
    python docs/run_tutorial.py --small    # the test suite's run: tiny sizes, nothing written

The code cells share one namespace and run in order, as a kernel would run them. What a cell
prints becomes its text output; every matplotlib figure a cell leaves open becomes a PNG
output (and is closed). ``--small`` sets ``GIJAX_TUTORIAL_SMALL=1``, which the notebook's
first cell reads to shrink every size and step count, so that ``tests/test_tutorial.py`` can
execute the whole walk-through in under a minute.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import io
import json
import os
import sys
import time
from pathlib import Path

NOTEBOOK = Path(__file__).resolve().with_name("tutorial.ipynb")


def _figures_as_png() -> list[str]:
    import matplotlib.pyplot as plt

    pngs = []
    for number in plt.get_fignums():
        buf = io.BytesIO()
        plt.figure(number).savefig(buf, format="png", dpi=80, bbox_inches="tight")
        pngs.append(base64.b64encode(buf.getvalue()).decode("ascii"))
    plt.close("all")
    return pngs


def run_notebook(path: Path = NOTEBOOK, small: bool = False, log=print) -> dict:
    """Execute the code cells of the notebook at ``path``; returns the notebook document with
    each code cell's ``outputs`` (and execution counts) filled in. An exception in a cell is
    raised with the cell's number added."""
    os.environ["GIJAX_TUTORIAL_SMALL"] = "1" if small else "0"
    import matplotlib

    matplotlib.use("Agg")
    doc = json.loads(Path(path).read_text())
    namespace: dict = {"__name__": "__tutorial__"}
    count = 0
    for index, cell in enumerate(doc["cells"]):
        if cell["cell_type"] != "code":
            continue
        count += 1
        source = "".join(cell["source"])
        out = io.StringIO()
        start = time.perf_counter()
        try:
            with contextlib.redirect_stdout(out):
                exec(compile(source, f"<tutorial cell {count}>", "exec"), namespace)
        except Exception as exc:
            raise RuntimeError(f"tutorial cell {count} (notebook cell {index}) failed: "
                               f"{type(exc).__name__}: {exc}") from exc
        outputs = []
        if out.getvalue():
            outputs.append({"output_type": "stream", "name": "stdout",
                            "text": out.getvalue().splitlines(keepends=True)})
        for png in _figures_as_png():
            outputs.append({"output_type": "display_data", "metadata": {},
                            "data": {"image/png": png, "text/plain": ["<Figure>"]}})
        cell["outputs"] = outputs
        cell["execution_count"] = count
        log(f"cell {count}: {time.perf_counter() - start:.1f} s")
    return doc


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true",
                        help="tiny sizes (GIJAX_TUTORIAL_SMALL=1) and nothing written: the "
                             "test suite's run")
    parser.add_argument("--notebook", default=str(NOTEBOOK), help="the notebook to run")
    args = parser.parse_args(argv)
    doc = run_notebook(Path(args.notebook), small=args.small)
    if not args.small:
        text = json.dumps(doc, indent=1, ensure_ascii=False) + "\n"
        tmp = Path(args.notebook).with_suffix(".ipynb.tmp")
        tmp.write_text(text)
        os.replace(tmp, args.notebook)
        print(f"wrote the outputs into {args.notebook}")
    return 0


if __name__ == "__main__":
    if str(Path(__file__).resolve().parents[1]) not in sys.path:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
