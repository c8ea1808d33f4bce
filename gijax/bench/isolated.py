"""Every preset measured in fresh processes: the JAX forward (whole and by stage) and the exported
file in onnxruntime, each with the peak resident set of its own process.

Peak memory is only meaningful per process: a process that has imported JAX, built a network
and compiled programs keeps much of that memory, so each measurement runs in a child of its own
(``python -m gijax.bench.isolated MODE ...``, one JSON line on stdout):

* ``jax``: builds the network (random weights, eval mode), compiles and times the whole forward
  (surrogate images in, the sweep grids computed from the rig inside, as
  ``benchmarks/bench_whole_vs_stages.py``), records the process's peak resident set, then
  compiles and times each stage alone (features, sweep, cost volume, U-Net, regression).
  Memory freed by the build and by the compilation is returned to the system after each
  (:func:`gijax.host_memory.release_freed_memory`), as :func:`gijax.store.load_model` does;
* ``export``: writes the ONNX file (grids baked in, raw fisheye images in);
* ``ort``: runs that file in a process that imports onnxruntime and numpy and not JAX (checked),
  under one memory profile of :mod:`gijax.export.ort_session`.

Batch 1, the 3-camera training rig, random inputs; times are medians of ``reps`` runs after one
warm-up. The JAX figures start from surrogates, the onnxruntime figures from raw fisheyes (the
exported graph includes the surrogate resampling). ``G16VV-plain`` is G16VV's structure with
plain features (no spherical conv), the network the authors' PyTorch figures were taken on.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Sequence

GB = 1e9
STAGES = ("features", "sweep", "cost_volume", "unet", "regress")
# The authors' PyTorch release on this machine kind (2-core CPU, batch 1, three cameras,
# 512 x 2048 surrogates, precomputed grids as inputs): seconds per forward, peak GB.
PYTORCH_REFERENCE = {"G16V-released": (3.8, 1.25), "G16VV-plain": (5.1, 1.46)}


def bench_config(name: str):
    """A preset by name, or ``<preset>-plain``: that preset with plain features."""
    from gijax.nn.presets import get_preset

    if name.endswith("-plain") and name != "-plain":
        base = get_preset(name[: -len("-plain")])
        return dataclasses.replace(base, name=name, features="plain")
    return get_preset(name)


def peak_rss_gb() -> float:
    """This process's resident-set high-water mark, GB (:func:`gijax.bench.memory.host_peak_rss_mib`)."""
    from gijax.bench.memory import MIB, host_peak_rss_mib

    return host_peak_rss_mib() * MIB / GB


def _median_time(fn: Callable, reps: int) -> float:
    """Median seconds of ``fn()`` over ``reps`` runs after one warm-up (blocking on results)."""
    from gijax.bench.timing import time_call

    return time_call(fn, warmup=1, reps=reps)[0].median


def stage_times(state, surrogates, stages, reps: int) -> dict:
    """``<stage>_s`` for each stage of :func:`gijax.bench.cases.programs.stage_programs`, each
    compiled alone and fed the previous stage's output, and their ``sum_s``."""
    import jax

    row, x = {}, (surrogates,)
    for key, (_, fn) in zip(STAGES, stages):
        compiled = jax.jit(fn).lower(state, *x).compile()
        row[key + "_s"] = _median_time(lambda c=compiled, a=x: c(state, *a), reps)
        out = compiled(state, *x)
        x = out if isinstance(out, tuple) else (out,)
    row["sum_s"] = sum(row[k + "_s"] for k in STAGES)
    return row


# ------------------------------------------------------------------------------- children

def jax_child(name: str, reps: int) -> dict:
    import jax

    from gijax.bench.cases.programs import stage_programs
    from gijax.host_memory import release_freed_memory

    row = {"preset": name, "peak_gb_imports": peak_rss_gb()}
    t0 = time.perf_counter()
    state, (sur, masks), whole, stages = stage_programs(bench_config(name))
    row["build_s"] = time.perf_counter() - t0
    # As gijax.store.load_model does after building a model, and a deployment after compiling.
    release_freed_memory()
    row["peak_gb_built"] = peak_rss_gb()
    t0 = time.perf_counter()
    whole_c = jax.jit(whole).lower(state, sur, masks).compile()
    row["compile_s"] = time.perf_counter() - t0
    release_freed_memory()
    row["whole_s"] = _median_time(lambda: whole_c(state, sur, masks), reps)
    # The whole forward's peak: taken before any stage program exists.
    row["peak_gb"] = peak_rss_gb()
    row.update(stage_times(state, sur, stages, reps))
    row["whole_over_sum"] = row["whole_s"] / row["sum_s"]
    row["jax"] = jax.__version__
    return row


def export_child(name: str, path: str, precision: str = "fp32", calibration: int = 1) -> dict:
    """Write ``name``'s file (random weights, the 3-camera training rig baked in) in
    ``precision``; int8 is calibrated on ``calibration`` rendered scenes."""
    import numpy as np

    from gijax.export.onnx_export import export_onnx
    from gijax.geometry.layouts import builtin_rig
    from gijax.model import create_model

    cfg = bench_config(name)
    model = create_model(cfg, seed=0)
    cand = np.geomspace(cfg.d_min, cfg.d_max, cfg.num_candidates).astype(np.float32)
    t0 = time.perf_counter()
    export_onnx(model, builtin_rig("paper-train"), cand, path, precision=precision,
                calibration_scenes=calibration)
    return {"preset": name, "precision": precision, "export_s": time.perf_counter() - t0,
            "onnx_mb": os.path.getsize(path) / 1e6, "peak_gb_export": peak_rss_gb()}


def ort_child(path: str, memory: str, reps: int, threads: int | None = None) -> dict:
    import numpy as np

    from gijax.export.ort_session import make_session

    row = {"memory": memory, "peak_gb_imports": peak_rss_gb()}
    t0 = time.perf_counter()
    sess = make_session(path, ["CPUExecutionProvider"], threads, memory)
    row["session_s"] = time.perf_counter() - t0
    row["peak_gb_session"] = peak_rss_gb()
    rng = np.random.default_rng(0)
    feed = {}
    for inp in sess.get_inputs():
        shape = [d if isinstance(d, int) else 1 for d in inp.shape]
        feed[inp.name] = (np.ones(shape, np.float32) if inp.name == "masks"
                          else rng.uniform(size=shape).astype(np.float32))
    names = [o.name for o in sess.get_outputs()]
    row["ort_s"] = _median_time(lambda: sess.run(names, feed), reps)
    row["peak_gb"] = peak_rss_gb()
    row["imported_jax"] = "jax" in sys.modules
    import onnxruntime

    row["onnxruntime"] = onnxruntime.__version__
    return row


def child_main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m gijax.bench.isolated",
                                description="One isolated measurement (see the module "
                                            "docstring); prints one JSON line.")
    sub = p.add_subparsers(dest="mode", required=True)
    j = sub.add_parser("jax")
    j.add_argument("preset")
    j.add_argument("--reps", type=int, default=3)
    e = sub.add_parser("export")
    e.add_argument("preset")
    e.add_argument("path")
    e.add_argument("--precision", default="fp32")
    e.add_argument("--calibration", type=int, default=1)
    o = sub.add_parser("ort")
    o.add_argument("path")
    o.add_argument("--memory", default="default")
    o.add_argument("--reps", type=int, default=3)
    o.add_argument("--threads", type=int, default=None)
    a = p.parse_args(argv)
    if a.mode == "jax":
        row = jax_child(a.preset, a.reps)
    elif a.mode == "export":
        row = export_child(a.preset, a.path, a.precision, a.calibration)
    else:
        row = ort_child(a.path, a.memory, a.reps, a.threads)
    print(json.dumps(row), flush=True)
    return 0


# ------------------------------------------------------------------------------- parent

def run_child(args: Sequence[str], log: Callable[[str], None] = print,
              module: str = "gijax.bench.isolated", python: str | None = None) -> dict:
    """Run ``python -m module *args`` in a fresh process (``python``: default this
    interpreter); the JSON row it prints last. RuntimeError naming the command and the end of
    its output when it fails."""
    cmd = [python or sys.executable, "-m", module, *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout)[-2000:]
        raise RuntimeError(f"{' '.join(cmd)} failed with exit status {proc.returncode}:\n{tail}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def measure_presets(presets: Sequence[str], reps: int = 3, onnx: bool = True,
                    memory_profiles: Sequence[str] = ("default", "lean", "low"),
                    log: Callable[[str], None] = print, keep_dir: str | Path | None = None
                    ) -> list[dict]:
    """One row per preset: the JAX child's figures, and (``onnx``) the export and one
    onnxruntime child per memory profile (``ort_<profile>_s``, ``ort_<profile>_peak_gb``).
    Presets that compute the same network (E8 and G8 differ only in their candidate list) are
    measured once; the later ones repeat the figures with ``same_as``. Exported files go to a
    temporary folder (or ``keep_dir``)."""
    from gijax.bench.cases.programs import structure

    rows, measured = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(keep_dir) if keep_dir else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name in presets:
            key = structure(bench_config(name))
            if key in measured:
                rows.append({**measured[key], "preset": name, "same_as": measured[key]["preset"]})
                continue
            log(f"isolated {name}: JAX ...")
            row = run_child(["jax", name, "--reps", reps], log)
            ref = PYTORCH_REFERENCE.get(name)
            if ref:
                row["pytorch_s"], row["pytorch_peak_gb"] = ref
            if onnx:
                path = folder / f"{name}.onnx"
                log(f"isolated {name}: export ...")
                row.update({k: v for k, v in run_child(["export", name, path], log).items()
                            if k in ("export_s", "onnx_mb")})
                for prof in memory_profiles:
                    log(f"isolated {name}: onnxruntime ({prof}) ...")
                    got = run_child(["ort", path, "--memory", prof, "--reps", reps], log)
                    for k in ("ort_s", "peak_gb", "peak_gb_session", "session_s",
                              "imported_jax"):
                        row[f"ort_{prof}_{k.removeprefix('ort_')}"] = got[k]
                    row["onnxruntime"] = got["onnxruntime"]
            rows.append(row)
            measured[key] = row
            log("  " + ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                                 for k, v in row.items() if k.endswith(("_s", "_gb", "sum"))))
    return rows


def versus_fp32(rows: Sequence[dict]) -> list[dict]:
    """``rows`` (one per preset and precision) with ``speedup_vs_fp32`` (the fp32 file's
    seconds over this file's) and ``peak_vs_fp32`` (this file's peak over the fp32 file's),
    taken against the fp32 row of the same preset; None where that preset has no fp32 row."""
    fp32 = {r["preset"]: r for r in rows if r["precision"] == "fp32"}
    out = []
    for r in rows:
        ref = fp32.get(r["preset"])
        out.append({**r, "speedup_vs_fp32": ref["ort_s"] / r["ort_s"] if ref else None,
                    "peak_vs_fp32": r["peak_gb"] / ref["peak_gb"] if ref else None})
    return out


def measure_precisions(presets: Sequence[str], precisions: Sequence[str] = ("fp32", "fp16",
                                                                              "int8"),
                       reps: int = 3, calibration: int = 1, threads: int | None = None,
                       log: Callable[[str], None] = print,
                       keep_dir: str | Path | None = None) -> list[dict]:
    """One row per preset and precision: the file exported in that precision (random weights,
    int8 calibrated on ``calibration`` rendered scenes; export seconds and the exporting
    process's peak) and run by onnxruntime (CPU, default memory profile) in a fresh process
    without JAX: median seconds per forward over ``reps`` after one warm-up, the process's
    peak resident set, and the ratios of :func:`versus_fp32`."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(keep_dir) if keep_dir else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name in presets:
            for prec in precisions:
                path = folder / f"{name}-{prec}.onnx"
                log(f"precision {name} {prec}: export ...")
                row = run_child(["export", name, path, "--precision", prec,
                                 "--calibration", calibration], log)
                log(f"precision {name} {prec}: onnxruntime ...")
                args = ["ort", path, "--reps", reps]
                if threads:
                    args += ["--threads", threads]
                got = run_child(args, log)
                row.update({k: got[k] for k in ("ort_s", "peak_gb", "peak_gb_session",
                                                "session_s", "imported_jax", "onnxruntime")})
                row["calibration_scenes"] = calibration if prec == "int8" else None
                rows.append(row)
                log(f"  {name} {prec}: {row['ort_s']:.3f} s, peak {row['peak_gb']:.2f} GB, "
                    f"{row['onnx_mb']:.1f} MB")
                if not keep_dir:
                    path.unlink()
    return versus_fp32(rows)


if __name__ == "__main__":
    raise SystemExit(child_main())
