"""The classical sphere-sweep baseline (RTSS) per camera count."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from gijax.bench.cases.context import Context, program_row, timing_row
from gijax.bench.cost import compile_fn
from gijax.bench.memory import CaseMemory
from gijax.bench.rigs import polygon_rig
from gijax.bench.timing import linear_increment, paired_ratio, timing_stats, time_alternating


def _rtss_program(ctx: Context, cameras: int):
    from gijax.baseline.rtss import RTSSConfig, sphere_sweep
    from gijax.geometry.panorama import Panorama

    s = ctx.settings
    rig = polygon_rig(cameras, image_scale=s.rtss_scale)
    cam = rig.cameras[0]
    rng = np.random.default_rng(0)
    images = jnp.asarray(rng.uniform(size=(cameras, cam.height, cam.width, 3)), jnp.float32)
    masks = jnp.ones((cameras, cam.height, cam.width), jnp.float32)
    cand = jnp.asarray(np.geomspace(0.5, 100.0, s.rtss_candidates), jnp.float32)
    pano = Panorama.hemisphere(*s.rtss_pano)
    config = RTSSConfig(name=f"RS-E{s.rtss_candidates}", num_candidates=s.rtss_candidates,
                        match_size=min(s.rtss_match, cam.width))

    # The baseline's jitted core (rtss_predict checks the candidate values with numpy, so it
    # cannot be traced); the checks are done once here instead.
    def run(images, masks):
        return sphere_sweep(rig, images, masks, cand, pano, config)["inv_distance"]

    return compile_fn(run, images, masks), (images, masks), cam.width


def rtss(ctx: Context) -> dict:
    """The classical sphere-sweep baseline per camera count, alternating, with the per-camera
    increment."""
    s = ctx.settings
    progs, rows = {}, []
    for n in s.rtss_cameras:
        ctx.log(f"rtss {n} cameras ...")
        with CaseMemory() as mem:
            t0 = time.perf_counter()
            compiled, args, width = _rtss_program(ctx, n)
            compile_s = time.perf_counter() - t0
            jax.block_until_ready(compiled(*args))
        progs[n] = (compiled, args)
        rows.append({"cameras": n, "candidates": s.rtss_candidates, "image": width,
                     "match": min(s.rtss_match, width), "pano": "x".join(map(str, s.rtss_pano)),
                     "compile_s": compile_s, **mem.result()})
    times = time_alternating({n: (lambda c=c, a=a: c(*a)) for n, (c, a) in progs.items()},
                             warmup=max(ctx.warmup - 1, 0), reps=ctx.reps)
    for row in rows:
        stats = timing_stats(times[row["cameras"]])
        row.update(timing_row(stats))
        row.update(program_row(progs[row["cameras"]][0], stats.median, ctx.limits))
    out = {"rows": rows}
    if len(rows) > 1:
        out["ms_per_camera"] = linear_increment([r["cameras"] for r in rows],
                                                [r["ms_median"] for r in rows])
        first = rows[0]["cameras"]
        for row in rows[1:]:
            row[f"ratio_vs_{first}cam"] = paired_ratio(times[row["cameras"]], times[first]).median
    return out
