"""Project / unproject throughput per camera model, jitted, on the default JAX device.

Prints a table and writes JSON (``--out``, default ``benchmarks/out/bench_cameras.json``).
Each timing is the best of ``--repeats`` runs on ``--points`` points after one warm-up call.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from gijax.geometry import cameras as C
from gijax.io.paths import write_json_atomic

CAMERAS = {
    "ds": dict(fx=232.0, fy=232.0, cx=611.5, cy=513.5, xi=-0.203, alpha=0.589),
    "eucm": dict(fx=232.0, fy=232.0, cx=611.5, cy=513.5, alpha=0.62, beta=1.1),
    "kb": dict(fx=300.0, fy=300.0, cx=611.5, cy=513.5, k1=0.01, k2=-0.004, k3=0.001, k4=-2e-4),
    "equidistant": dict(fx=300.0, fy=300.0, cx=611.5, cy=513.5),
}


def _time(fn, arg, repeats):
    jax.block_until_ready(fn(arg))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(arg))
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=1_000_000,
                    help="points projected and unprojected per timing")
    ap.add_argument("--repeats", type=int, default=5,
                    help="timings per camera model (the best is reported)")
    ap.add_argument("--out", default="benchmarks/out/bench_cameras.json",
                    help="where the JSON results are written")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    v = rng.normal(size=(args.points, 3)).astype(np.float32)
    v[:, 2] = np.abs(v[:, 2])
    pts = jnp.asarray(v)
    px = jnp.asarray(rng.uniform([0, 0], [1223, 1027], (args.points, 2)).astype(np.float32))
    rows = []
    for model, params in CAMERAS.items():
        cam = C.make_camera(model, params, 1224, 1028, 195.0)
        proj = jax.jit(lambda p, cam=cam: C.project(cam, p))
        unproj = jax.jit(lambda q, cam=cam: C.unproject(cam, q))
        tp = _time(proj, pts, args.repeats)
        tu = _time(unproj, px, args.repeats)
        rows.append(dict(model=model, points=args.points, project_s=tp, unproject_s=tu,
                         project_mpts_s=args.points / tp / 1e6,
                         unproject_mpts_s=args.points / tu / 1e6))
    print(f"{'model':<12}{'project Mpts/s':>16}{'unproject Mpts/s':>18}")
    for r in rows:
        print(f"{r['model']:<12}{r['project_mpts_s']:>16.1f}{r['unproject_mpts_s']:>18.1f}")
    meta = dict(device=str(jax.devices()[0]), jax=jax.__version__, cpu_count=os.cpu_count(),
                machine=platform.machine(), loadavg=os.getloadavg(), dtype="float32")
    out = write_json_atomic(args.out, dict(meta=meta, results=rows))
    print(f"wrote {out}  (device {meta['device']}, load average {meta['loadavg'][0]:.1f})")


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    main()
