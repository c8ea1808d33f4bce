"""onnxruntime vs JAX: latency and peak memory of the same model on the same input.

For each preset the model (random weights, seed 0) is exported with the rig baked in, and both
paths run one rendered sample of the paper's training rig: JAX = surrogate resampling + the
network in one jitted call (gijax's own path, CPU-tuned 3-D convolutions), onnxruntime = the
exported file (all graph optimisations). Runs alternate JAX / onnxruntime after a warm-up;
the table gives medians and the ratio JAX / onnxruntime (> 1: onnxruntime faster). Peak memory
is the largest growth of the resident set (polled every 2 ms) of a fresh child process per
backend, from just before the session / compilation to the end of its runs (compiled code,
buffers and activations; the weights already in memory and the imports are not counted).

  python benchmarks/bench_onnx.py                 # G16V-cpu and G16VV-cpu
  python benchmarks/bench_onnx.py --paper         # plus G16V and G16VV at paper size
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _setup(preset: str, workdir: str):
    from gijax.candidates.spec import model_candidates
    from gijax.export.onnx_export import export_onnx, rendered_inputs
    from gijax.io.rigfile import load_rig
    from gijax.model import create_model

    rig = load_rig("paper-train")
    model = create_model(preset, seed=0)
    cfg = model.config
    cand, _ = model_candidates("train", rig, cfg)
    path = os.path.join(workdir, f"{preset}.onnx")
    if not os.path.exists(path):
        export_onnx(model, rig, cand, path)
    images, masks = rendered_inputs(model.config, rig, seed=0)
    return model, rig, cand, path, images, masks


def _jax_runner(model, rig, cand):
    import jax.numpy as jnp
    from flax import nnx

    from gijax.export.onnx_export import eval_view, rig_at_model_size
    from gijax.model import model_grids
    from gijax.sweep.grids import fisheye_surrogates, surrogate_resampling

    cfg = model.config
    run_rig = rig_at_model_size(cfg, rig)
    c = jnp.asarray(cand, jnp.float32)

    @nnx.jit
    def fwd(view, images, masks):
        sur, sur_masks = fisheye_surrogates(surrogate_resampling(run_rig, cfg.surrogate_hw),
                                            images, masks)
        return view(sur, sur_masks, model_grids(cfg, run_rig, c))["inv_distance"]

    view = eval_view(model)
    return lambda images, masks: np.asarray(fwd(view, images, masks))


def _ort_runner(path):
    from gijax.export.ort_session import make_session

    sess = make_session(path, ["CPUExecutionProvider"])
    return lambda images, masks: sess.run(["inv_distance"], {"images": images,
                                                             "masks": masks})[0]


def _rss_mb() -> float:
    """Current resident set size of this process, MiB."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def child(preset: str, backend: str, workdir: str, repeats: int) -> None:
    """Peak-memory probe: one backend in this process, RSS polled every 2 ms; prints JSON."""
    import threading

    model, rig, cand, path, images, masks = _setup(preset, workdir)
    before = _rss_mb()
    peak = [before]
    done = threading.Event()

    def poll():
        while not done.is_set():
            peak[0] = max(peak[0], _rss_mb())
            time.sleep(0.002)

    th = threading.Thread(target=poll, daemon=True)
    th.start()
    run = _jax_runner(model, rig, cand) if backend == "jax" else _ort_runner(path)
    for _ in range(repeats):
        run(images, masks)
    done.set()
    th.join()
    print(json.dumps({"peak_growth_mb": peak[0] - before, "peak_mb": peak[0]}))


def bench(preset: str, workdir: str, repeats: int) -> dict:
    t0 = time.perf_counter()
    model, rig, cand, path, images, masks = _setup(preset, workdir)
    setup_s = time.perf_counter() - t0
    run_jax, run_ort = _jax_runner(model, rig, cand), _ort_runner(path)
    a, b = run_jax(images, masks), run_ort(images, masks)  # warm-up (compiles)
    diff = float(np.max(np.abs(a - b)))
    tj, to = [], []
    for _ in range(repeats):
        s = time.perf_counter()
        run_jax(images, masks)
        tj.append(time.perf_counter() - s)
        s = time.perf_counter()
        run_ort(images, masks)
        to.append(time.perf_counter() - s)
    mem = {}
    for backend in ("jax", "onnxruntime"):
        out = subprocess.run([sys.executable, __file__, "--child", preset, backend, workdir,
                              str(min(repeats, 2))], capture_output=True, text=True,
                             cwd=str(ROOT))
        line = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
        mem[backend] = json.loads(line[-1]) if line else {"error": out.stderr[-300:]}
    cfg = model.config
    return {"preset": preset, "surrogate_hw": list(cfg.surrogate_hw),
            "output_hw": list(cfg.output_hw), "repeats": repeats, "setup_s": setup_s,
            "jax_ms": 1e3 * float(np.median(tj)), "ort_ms": 1e3 * float(np.median(to)),
            "ratio_jax_over_ort": float(np.median(tj) / np.median(to)),
            "max_abs_diff_inv_distance": diff,
            "jax_peak_growth_mb": mem["jax"].get("peak_growth_mb"),
            "ort_peak_growth_mb": mem["onnxruntime"].get("peak_growth_mb"),
            "onnx_mb": os.path.getsize(path) / 2**20}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paper", action="store_true", help="also the paper-size G16V and G16VV")
    ap.add_argument("--repeats", type=int, default=10, help="alternating runs at CPU size")
    ap.add_argument("--paper-repeats", type=int, default=2,
                    help="alternating runs at paper size (with --paper)")
    ap.add_argument("--presets", nargs="+", default=["G16V-cpu", "G16VV-cpu"],
                    help="CPU-size presets to export and time")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "bench_onnx.json"),
                    help="where the JSON results are written")
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child[0], args.child[1], args.child[2], int(args.child[3]))
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for p in args.presets:
            rows.append(bench(p, workdir, args.repeats))
        if args.paper:
            for p in ("G16V", "G16VV"):
                rows.append(bench(p, workdir, args.paper_repeats))
    head = (f"{'preset':10s} {'output':>9s} {'JAX ms':>9s} {'ORT ms':>9s} {'JAX/ORT':>8s} "
            f"{'JAX MB':>8s} {'ORT MB':>8s} {'|d inv|':>9s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['preset']:10s} {'x'.join(map(str, r['output_hw'])):>9s} {r['jax_ms']:9.1f} "
              f"{r['ort_ms']:9.1f} {r['ratio_jax_over_ort']:8.2f} "
              f"{r['jax_peak_growth_mb'] or float('nan'):8.0f} "
              f"{r['ort_peak_growth_mb'] or float('nan'):8.0f} "
              f"{r['max_abs_diff_inv_distance']:9.1e}")
    from gijax.io.paths import write_json_atomic

    out = write_json_atomic(args.out, {"cpu_count": os.cpu_count(), "rows": rows})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
