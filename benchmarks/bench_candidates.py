"""Rig-aware GI candidate solve and gradient times, jitted, on the current backend.

Times ``rig_gi_candidates`` (n = 8, 16, 32) on the 3-camera (paper-test2) and 4-camera
(paper-test3) layouts after compilation, and the gradient of a scalar function of the list with
respect to the camera translations. Prints a table and writes JSON (``--out``).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from gijax.candidates import rig_gi_candidates
from gijax.candidates.rig_aware import DEFAULT_PANO, as_float_rig
from gijax.geometry.layouts import builtin_rig
from gijax.io.paths import write_json_atomic


def _time(fn, repeats: int) -> tuple[float, float]:
    """Median and minimum wall time of ``fn()`` (blocking), milliseconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), float(np.min(times))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="benchmarks/out/bench_candidates.json",
                        help="where the JSON results are written")
    parser.add_argument("--repeats", type=int, default=50,
                        help="timed calls per case")
    parser.add_argument("--x64", action="store_true", help="float64 (default float32)")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", bool(args.x64))

    rows = []
    for name in ("paper-test2", "paper-test3"):
        rig = as_float_rig(builtin_rig(name))
        for n in (8, 16, 32):
            solve = jax.jit(lambda r, n=n: rig_gi_candidates(r, n, 0.5, 100.0))
            t0 = time.perf_counter()
            jax.block_until_ready(solve(rig))
            compile_s = time.perf_counter() - t0
            med, best = _time(lambda: solve(rig), args.repeats)

            def loss(t, rig=rig, n=n):
                return jnp.sum(jnp.log(rig_gi_candidates(rig.replace(translations=t), n)))

            grad = jax.jit(jax.grad(loss))
            t0 = time.perf_counter()
            jax.block_until_ready(grad(rig.translations))
            grad_compile_s = time.perf_counter() - t0
            gmed, gbest = _time(lambda: grad(rig.translations), args.repeats)
            rows.append(dict(rig=name, cameras=rig.num_cameras, n=n, solve_ms=med,
                             solve_min_ms=best, compile_s=compile_s, grad_ms=gmed,
                             grad_min_ms=gbest, grad_compile_s=grad_compile_s))

    dtype = "float64" if args.x64 else "float32"
    rays = DEFAULT_PANO.height * DEFAULT_PANO.width
    print(f"rig-aware GI solve, {rays} panorama rays, {dtype}, backend {jax.default_backend()}, "
          f"median of {args.repeats}")
    print(f"{'rig':12s} {'cams':>4s} {'n':>3s} {'solve ms':>9s} {'min ms':>7s} {'grad ms':>8s} "
          f"{'min ms':>7s} {'compile s':>9s}")
    for r in rows:
        print(f"{r['rig']:12s} {r['cameras']:4d} {r['n']:3d} {r['solve_ms']:9.3f} "
              f"{r['solve_min_ms']:7.3f} {r['grad_ms']:8.3f} {r['grad_min_ms']:7.3f} "
              f"{r['compile_s']:9.2f}")
    out = dict(benchmark="candidates", dtype=dtype, backend=jax.default_backend(),
               panorama_rays=rays, repeats=args.repeats, rows=rows)
    write_json_atomic(args.out, out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    raise SystemExit(main())
