"""The exported ONNX graph in onnxruntime against the same function jitted in JAX."""

from __future__ import annotations

import os
import tempfile
import time

import jax.numpy as jnp
import numpy as np

from gijax.bench.cases.context import Context, program_row, timing_row
from gijax.bench.cost import compile_fn
from gijax.bench.memory import MIB, CaseMemory
from gijax.bench.timing import paired_ratio, timing_stats, time_alternating
from gijax.geometry.layouts import builtin_rig
from gijax.nn.presets import get_preset


def onnx_vs_jax(ctx: Context) -> dict:
    """The exported graph in onnxruntime against the same function jitted in JAX (rig and
    grids baked in, raw fisheye images in), alternating runs, ratio per round."""
    from gijax.export.onnx_export import build_function, eval_view, export_onnx, rig_at_model_size
    from gijax.export.ort_session import default_providers, make_session
    from gijax.model import create_model

    providers = (["CPUExecutionProvider"] if ctx.device.platform == "cpu"
                 else default_providers())
    rows = []
    for name in ctx.settings.onnx_presets:
        ctx.log(f"onnx vs jax {name} ...")
        cfg = get_preset(name)
        rig = builtin_rig("paper-train")
        model = create_model(cfg, seed=0)
        cand = np.geomspace(cfg.d_min, cfg.d_max, cfg.num_candidates).astype(np.float32)
        run_rig = rig_at_model_size(cfg, rig)
        cam = run_rig.cameras[0]
        rng = np.random.default_rng(0)
        images = rng.uniform(size=(1, run_rig.num_cameras, cam.height, cam.width, 3)
                             ).astype(np.float32)
        masks = np.ones(images.shape[:4], np.float32)
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, f"{name}.onnx")
            t0 = time.perf_counter()
            export_onnx(model, rig, cand, path)
            export_s = time.perf_counter() - t0
            size_mib = os.path.getsize(path) / MIB
            with CaseMemory() as ort_mem:
                sess = make_session(path, providers)
                ort_out = sess.run(["inv_distance"], {"images": images, "masks": masks})[0]
        fn = build_function(eval_view(model), run_rig, cand, rig_as_input=False)
        j_images, j_masks = jnp.asarray(images), jnp.asarray(masks)
        with CaseMemory() as jax_mem:
            t0 = time.perf_counter()
            compiled = compile_fn(fn, j_images, j_masks)
            compile_s = time.perf_counter() - t0
            jax_out = np.asarray(compiled(j_images, j_masks)[0])
        times = time_alternating(
            {"jax": lambda: compiled(j_images, j_masks),
             "ort": lambda: sess.run(["inv_distance"], {"images": images, "masks": masks})},
            warmup=ctx.warmup, reps=ctx.reps)
        js, os_ = timing_stats(times["jax"]), timing_stats(times["ort"])
        ratio = paired_ratio(times["jax"], times["ort"])
        row = {"preset": name, "provider": sess.get_providers()[0], "export_s": export_s,
               "onnx_mib": size_mib, "jax_compile_s": compile_s,
               **timing_row(js, "jax_"), **timing_row(os_, "ort_"),
               "ratio_jax_over_ort": ratio.median, "ratio_q1": ratio.q1, "ratio_q3": ratio.q3,
               "ratio_iqr": f"{ratio.q1:.2f}-{ratio.q3:.2f}",
               "jax_rss_growth_mib": jax_mem.result()["rss_growth_mib"],
               "ort_rss_growth_mib": ort_mem.result()["rss_growth_mib"],
               "max_abs_diff_inv_distance": float(np.max(np.abs(jax_out - ort_out)))}
        row.update(program_row(compiled, js.median, ctx.limits))
        if ctx.limits:
            row["ort_frac_peak_flops"] = row["gflop"] * 1e9 / os_.median / ctx.limits[
                "flops_per_s"]
        rows.append(row)
    return {"rows": rows}
