"""ONNX export time: jax2onnx's own graph lookups against gijax's constant-time ones.

For each preset (random weights, seed 0, the paper's training rig) the model is exported with
the rig baked in and with the rig as an input, alternating between jax2onnx's converter as it
ships and the converter under :func:`gijax.export.converter_lookups.fast_lookups` (what
``export_onnx`` uses), after one warm-up export of each kind. Each file's SHA-256 is compared
with the other mode's: the table says whether the bytes are the same.

  python benchmarks/bench_export.py                      # G16V-cpu and G16VV-cpu
  python benchmarks/bench_export.py --presets G16VV-cpu G16VV G16V-released
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MODES = ("jax2onnx", "gijax")


def bench(preset: str, rig_as_input: bool, rounds: int, folder: str) -> dict:
    import numpy as np

    from gijax.export import onnx_export
    from gijax.io.rigfile import load_rig
    from gijax.model import create_model

    fast = onnx_export.fast_lookups
    lookups = {"jax2onnx": lambda: contextlib.nullcontext(False), "gijax": fast}
    model = create_model(preset, seed=0)
    cfg = model.config
    cand = np.geomspace(cfg.d_min, cfg.d_max, cfg.num_candidates)
    rig = load_rig("paper-train")
    seconds = {m: [] for m in MODES}
    digests = {}
    try:
        for r in range(rounds + 1):                   # round 0 is the warm-up
            for mode in (MODES if r % 2 == 0 else MODES[::-1]):
                onnx_export.fast_lookups = lookups[mode]
                path = os.path.join(folder, f"{preset}-{mode}.onnx")
                t0 = time.perf_counter()
                onnx_export.export_onnx(model, rig, cand, path, rig_as_input=rig_as_input)
                if r:
                    seconds[mode].append(time.perf_counter() - t0)
                digests[mode] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    finally:
        onnx_export.fast_lookups = fast
    med = {m: statistics.median(seconds[m]) for m in MODES}
    return {"preset": preset, "rig_as_input": rig_as_input, "rounds": rounds,
            "seconds": seconds, "median_s": med, "speedup": med["jax2onnx"] / med["gijax"],
            "same_bytes": digests["jax2onnx"] == digests["gijax"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["G16V-cpu", "G16VV-cpu"],
                    help="network presets to export (paper-size names work too)")
    ap.add_argument("--rounds", type=int, default=3,
                    help="timed exports per mode and preset, after one warm-up each")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "bench_export.json"),
                    help="where the JSON results are written")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for preset in args.presets:
            for rig_as_input in (False, True):
                rows.append(bench(preset, rig_as_input, args.rounds, folder))
    from gijax.bench.report import text_table

    table = [{"preset": r["preset"], "rig": "input" if r["rig_as_input"] else "baked",
              "plain": r["median_s"]["jax2onnx"], "fast": r["median_s"]["gijax"],
              "speedup": r["speedup"], "same": "yes" if r["same_bytes"] else "NO"} for r in rows]
    print(text_table(table, [("preset", "preset"), ("rig", "rig"),
                             ("jax2onnx's lookups s", "plain", ".2f"),
                             ("gijax's s", "fast", ".2f"), ("speed-up", "speedup", ".2f"),
                             ("same bytes", "same")]))
    from gijax.bench.machine import machine_info
    from gijax.io.paths import write_json_atomic

    out = write_json_atomic(args.out, {"machine": machine_info(), "rows": rows})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
