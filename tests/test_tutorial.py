"""``docs/tutorial.ipynb`` runs top to bottom (at tiny sizes, ``docs/run_tutorial.py --small``)
and says what it claims: the gradient through the network is finite and non-zero, the export
agrees with JAX, the training loss is a number; the stored outputs are those of a full run."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "docs" / "tutorial.ipynb"


def _text(cell) -> str:
    return "".join("".join(o.get("text", [])) for o in cell.get("outputs", []))


def test_the_tutorial_runs_at_tiny_sizes(tmp_path):
    code = ("import json, sys; sys.path.insert(0, 'docs'); import run_tutorial\n"
            f"doc = run_tutorial.run_notebook(run_tutorial.NOTEBOOK, small=True, log=lambda m: None)\n"
            f"open({str(tmp_path / 'out.json')!r}, 'w').write(json.dumps(doc))")
    env = dict(os.environ, JAX_DISABLE_MOST_OPTIMIZATIONS="1", MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    doc = json.loads((tmp_path / "out.json").read_text())
    cells = [c for c in doc["cells"] if c["cell_type"] == "code"]
    texts = [_text(c) for c in cells]
    assert "tiny sizes" in texts[0]
    gradient = next(t for t in texts if "d loss / d candidate" in t)
    numbers = [float(x) for x in gradient.split("d loss / d candidate (per m):")[1]
               .split("\n")[0].strip(" []").split()]
    assert len(numbers) == 8 and np.all(np.isfinite(numbers)) and np.abs(numbers).max() > 0
    export = next(t for t in texts if "onnxruntime vs JAX" in t)
    # Compiled with most XLA optimisations off (for time), JAX's own rounding moves by up to
    # about 1e-4 1/m; the stored full run agrees within validate_export's 1e-4.
    diff = float(export.split("max |d inverse distance|")[1].split()[0])
    assert diff < 1e-3, export
    assert "loss: first" in next(t for t in texts if "loss: first" in t)
    # Every figure cell drew its figure.
    assert sum(o["output_type"] == "display_data" for c in cells for o in c["outputs"]) == 4


def test_the_stored_outputs_come_from_a_full_run():
    doc = json.loads(NOTEBOOK.read_text())
    cells = [c for c in doc["cells"] if c["cell_type"] == "code"]
    assert all(c["execution_count"] == i + 1 for i, c in enumerate(cells))
    assert "tiny sizes" not in _text(cells[0])
    assert any("agrees: True" in _text(c) for c in cells)
    assert sum(o["output_type"] == "display_data" for c in cells for o in c["outputs"]) == 4
