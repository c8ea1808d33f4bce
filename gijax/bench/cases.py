"""The benchmark cases. Each takes a :class:`Context` and returns a JSON-ready dict with
``rows`` (one dict per measured configuration) and case-level fields.

Times are seconds inside the code and milliseconds in the rows (``*_ms``); memory is MiB.
Every program is compiled once (``jax.jit(...).lower(...).compile()``), which also yields its
FLOPs and bytes (XLA cost analysis) and its memory (XLA memory analysis).
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.bench.cost import compile_fn, cost_of, efficiency, matmul_peak, memory_bandwidth
from gijax.bench.memory import MIB, CaseMemory, compiled_memory
from gijax.bench.rigs import (network_inputs, network_rig, polygon_rig, with_candidates)
from gijax.bench.timing import (linear_increment, paired_ratio, summarize, time_alternating,
                                time_call)
from gijax.geometry.layouts import builtin_rig
from gijax.nn.presets import ModelConfig, get_preset


@dataclasses.dataclass
class Context:
    """What every case needs: the suite's settings, the device, and the calibration."""

    settings: "object"  # gijax.bench.suite.SuiteSettings
    device: object
    limits: dict | None = None
    log: Callable[[str], None] = print

    @property
    def reps(self) -> int:
        return self.settings.reps

    @property
    def warmup(self) -> int:
        return self.settings.warmup


def _timing_row(stats, prefix: str = "") -> dict:
    return stats.as_dict(prefix=f"{prefix}ms_" if prefix else "ms_", factor=1e3)


def _program_row(compiled, seconds: float, limits) -> dict:
    row = {}
    mem = compiled_memory(compiled)
    if mem:
        row["xla_peak_mib"] = mem["peak_bytes"] / MIB
        row["xla_temp_mib"] = mem["temp_bytes"] / MIB
    row.update(efficiency(cost_of(compiled), seconds, limits))
    return row


# ------------------------------------------------------------------------------ calibration

def calibrate(ctx: Context) -> dict:
    """Measured matmul FLOP/s and memory bandwidth of the device (the limits of every figure)."""
    s = ctx.settings
    mm = matmul_peak(s.matmul_n, reps=max(ctx.reps, 5), device=ctx.device)
    bw = memory_bandwidth(s.bandwidth_mib, reps=max(ctx.reps, 5), device=ctx.device)
    ctx.limits = {"flops_per_s": mm["flops_per_s"], "bytes_per_s": bw["bytes_per_s"]}
    ctx.log(f"calibration: matmul {mm['flops_per_s'] / 1e9:.1f} GFLOP/s (n={mm['n']}), "
            f"bandwidth {bw['bytes_per_s'] / 1e9:.1f} GB/s")
    return {"matmul": mm, "bandwidth": bw, "limits": dict(ctx.limits),
            "rows": [{"what": f"matmul {mm['n']}^3 float32", "ms_median": 1e3 * mm["median_s"],
                      "ms_min": 1e3 * mm["min_s"], "gflops_per_s": mm["flops_per_s"] / 1e9,
                      "check": f"XLA flops {mm['xla_flops']:.3g} = 2n^3 {mm['flops']:.3g}"},
                     {"what": f"copy {bw['mib']} MiB", "ms_median": 1e3 * bw["copy_median_s"],
                      "gbytes_per_s": bw["copy_bytes_per_s"] / 1e9,
                      "check": f"XLA bytes {bw['copy_xla_bytes']:.3g}"},
                     {"what": f"sum {bw['mib']} MiB", "ms_median": 1e3 * bw["reduce_median_s"],
                      "gbytes_per_s": bw["reduce_bytes_per_s"] / 1e9,
                      "check": f"XLA bytes {bw['reduce_xla_bytes']:.3g}"}]}


# ------------------------------------------------------------------------------ the network

def _structure(cfg: ModelConfig) -> ModelConfig:
    """Fields that change the computation (the candidate kind and the loss do not)."""
    return dataclasses.replace(cfg, name="", candidates="gi", loss="volume",
                               mask_augmentation=False)


def eval_forward_program(cfg: ModelConfig, rig, batch: int = 1, seed: int = 0):
    """(compiled, args) of the eval-mode forward pass (surrogates -> outputs) of a fresh
    network of ``cfg`` on ``rig`` (already at the network's image size)."""
    from gijax.model import create_model

    model = create_model(cfg, seed=seed)
    model.eval()
    graphdef, state = nnx.split(model)
    sur, masks, cand = network_inputs(cfg, rig.num_cameras, batch, seed)

    def forward(state, sur, masks, rig, cand):
        out = nnx.merge(graphdef, state)(sur, masks, rig, cand)
        return {k: out[k] for k in ("inv_distance", "distance", "entropy", "valid")}

    args = (state, sur, masks, rig, cand)
    return compile_fn(forward, *args), args


def _measure_program(ctx: Context, build: Callable[[], tuple]) -> tuple[dict, object, tuple]:
    """Compile (timed, memory watched) and run a program; returns (row, compiled, args)."""
    with CaseMemory() as mem:
        t0 = time.perf_counter()
        compiled, args = build()
        compile_s = time.perf_counter() - t0
        jax.block_until_ready(compiled(*args))
    stats, _ = time_call(lambda: compiled(*args), warmup=max(ctx.warmup - 1, 0), reps=ctx.reps)
    row = {"compile_s": compile_s, **_timing_row(stats), **mem.result(),
           **_program_row(compiled, stats.median, ctx.limits)}
    return row, compiled, args


def forward(ctx: Context) -> dict:
    """Forward latency, memory and FLOP efficiency per preset (3-camera training rig)."""
    rows, done = [], {}
    base_rig = builtin_rig("paper-train")
    for name in ctx.settings.presets:
        cfg = get_preset(name)
        key = _structure(cfg)
        if key not in done:
            ctx.log(f"forward {name} ...")
            rig = network_rig(base_rig, cfg)
            row, _, _ = _measure_program(ctx, lambda: eval_forward_program(cfg, rig))
            done[key] = (name, row)
        first, row = done[key]
        rows.append({"preset": name, "same_as": None if first == name else first,
                     "surrogate": "x".join(map(str, cfg.surrogate_hw)),
                     "output": "x".join(map(str, cfg.output_hw)), **row})
    return {"rows": rows}


def _sweep(cfg, feats, masks, rig, cand):
    """The sweep stage as the forward runs it: grids from the rig, then sampling."""
    from gijax.model import Grids, sweep, sweep_grids

    px, ok = sweep_grids(rig, cand, cfg)
    return sweep(feats, masks, Grids(None, None, px, ok, cand), cfg.sweep_boundary)


def sweep(ctx: Context) -> dict:
    """The sphere sweep alone (grids from the rig + sampling of features and masks), with its
    memory traffic against the measured bandwidth."""
    cfg = get_preset(ctx.settings.sweep_preset)
    rig = network_rig(builtin_rig("paper-train"), cfg)
    n = rig.num_cameras
    hf, wf = cfg.feature_hw
    rng = np.random.default_rng(0)
    feats = jnp.asarray(rng.standard_normal((1, n, hf, wf, cfg.feature_channels)), jnp.float32)
    _, masks, cand = network_inputs(cfg, n)

    def run(feats, masks, rig, cand):
        return _sweep(cfg, feats, masks, rig, cand)

    ctx.log(f"sweep {cfg.name} ...")
    row, compiled, _ = _measure_program(ctx, lambda: (compile_fn(run, feats, masks, rig, cand),
                                                      (feats, masks, rig, cand)))
    mem = compiled_memory(compiled)
    # The least traffic: read the inputs once, write the outputs once.
    min_bytes = mem.get("argument_bytes", 0) + mem.get("output_bytes", 0)
    row.update({"preset": cfg.name, "cameras": n, "candidates": cfg.num_candidates,
                "volume": f"{n}x{cfg.num_candidates}x{cfg.cost_hw[0]}x{cfg.cost_hw[1]}x"
                          f"{cfg.feature_channels}",
                "min_gbytes": min_bytes / 1e9})
    if ctx.limits:
        secs = row["ms_median"] / 1e3
        row["min_bytes_frac_bandwidth"] = min_bytes / secs / ctx.limits["bytes_per_s"]
        row["bandwidth_bound_ms"] = 1e3 * min_bytes / ctx.limits["bytes_per_s"]
    return {"rows": [row]}


def stage_programs(cfg: ModelConfig, seed: int = 0) -> tuple:
    """A fresh eval-mode network of ``cfg`` on the 3-camera training rig, cut as its forward
    runs: ``(state, surrogates, whole, stages)``. ``whole(state, surrogates, masks)`` is the
    jittable forward (inverse distance); ``stages`` lists ``(name, fn)`` for the feature
    extractor, sweep (grids from the rig included), cost volume, U-Net and regression, each
    ``fn(state, *outputs of the previous stage)``."""
    from gijax.model import create_model
    from gijax.nn import regress

    rig = network_rig(builtin_rig("paper-train"), cfg)
    model = create_model(cfg, seed=seed)
    model.eval()
    graphdef, state = nnx.split(model)
    sur, masks, cand = network_inputs(cfg, rig.num_cameras)
    b, n, hs, ws, _ = sur.shape

    def whole(state, sur, masks):
        return nnx.merge(graphdef, state)(sur, masks, rig, cand)["inv_distance"]

    def features(state, sur):
        feats = nnx.merge(graphdef, state).features(sur.reshape(b * n, hs, ws, 3))
        return feats.reshape(b, n, *feats.shape[1:])

    def sweep_stage(state, feats):
        return _sweep(cfg, feats, masks, rig, cand)

    def cost_volume(state, sampled, valid):
        return nnx.merge(graphdef, state).cost_volume(sampled, valid.astype(sampled.dtype))

    def unet(state, volume):
        return nnx.merge(graphdef, state).unet(volume)

    def regression(state, logits):
        return regress(logits, cand, cfg.output_hw)["inv_distance"]

    stages = [("features", features), ("sweep", sweep_stage), ("cost volume", cost_volume),
              ("U-Net", unet), ("regression", regression)]
    return state, (sur, masks), whole, stages


def stages(ctx: Context) -> dict:
    """The forward pass cut into its stages (feature extractor, sweep, cost volume, U-Net,
    regression), each compiled and timed alone with its FLOPs and bytes: where the time goes
    and how far each stage is from the machine's limits."""
    cfg = get_preset(ctx.settings.sweep_preset)
    state, (sur, _), _, stage_fns = stage_programs(cfg)
    rows, x = [], (sur,)
    for name, fn in stage_fns:
        ctx.log(f"stage {cfg.name} {name} ...")
        args = (state, *x)
        row, compiled, _ = _measure_program(ctx, lambda fn=fn, args=args: (compile_fn(fn, *args),
                                                                           args))
        out = compiled(*args)
        x = out if isinstance(out, tuple) else (out,)
        shapes = [tuple(a.shape) for a in jax.tree_util.tree_leaves(out)][:1]
        rows.append({"preset": cfg.name, "stage": name, "output": "x".join(map(str, shapes[0])),
                     **{k: v for k, v in row.items() if not k.startswith("rss")}})
    total = sum(r["ms_median"] for r in rows)
    for r in rows:
        r["share"] = r["ms_median"] / total
    return {"rows": rows, "sum_ms": total}


# ------------------------------------------------------------------------------ JAX vs ORT

def onnx_vs_jax(ctx: Context) -> dict:
    """The exported graph in onnxruntime against the same function jitted in JAX (rig and
    grids baked in, raw fisheye images in), alternating runs, ratio per round."""
    from gijax.export.onnx_export import build_function, eval_view, export_onnx, model_rig
    from gijax.export.ort_predict import default_providers, make_session
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
        run_rig = model_rig(cfg, rig)
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
        js, os_ = summarize(times["jax"]), summarize(times["ort"])
        ratio = paired_ratio(times["jax"], times["ort"])
        row = {"preset": name, "provider": sess.get_providers()[0], "export_s": export_s,
               "onnx_mib": size_mib, "jax_compile_s": compile_s,
               **_timing_row(js, "jax_"), **_timing_row(os_, "ort_"),
               "ratio_jax_over_ort": ratio.median, "ratio_q1": ratio.q1, "ratio_q3": ratio.q3,
               "ratio_iqr": f"{ratio.q1:.2f}-{ratio.q3:.2f}",
               "jax_rss_growth_mib": jax_mem.result()["rss_growth_mib"],
               "ort_rss_growth_mib": ort_mem.result()["rss_growth_mib"],
               "max_abs_diff_inv_distance": float(np.max(np.abs(jax_out - ort_out)))}
        row.update(_program_row(compiled, js.median, ctx.limits))
        if ctx.limits:
            row["ort_frac_peak_flops"] = row["gflop"] * 1e9 / os_.median / ctx.limits[
                "flops_per_s"]
        rows.append(row)
    return {"rows": rows}


# ------------------------------------------------------------------------------ candidates

def candidates(ctx: Context) -> dict:
    """Rig-aware GI candidate solve and the gradient of the list w.r.t. the camera positions."""
    from gijax.candidates import rig_gi_candidates
    from gijax.candidates.rig_aware import as_float_rig

    rows = []
    for rig_name in ctx.settings.candidate_rigs:
        rig = as_float_rig(builtin_rig(rig_name))
        for n in ctx.settings.candidate_counts:
            ctx.log(f"candidates {rig_name} n={n} ...")

            def solve(t, rig=rig, n=n):
                return rig_gi_candidates(rig.replace(translations=t), n)

            def loss(t, solve=solve):
                return jnp.sum(jnp.log(solve(t)))

            t = rig.translations
            row = {"rig": rig_name, "cameras": rig.num_cameras, "n": n}
            for what, fn in (("solve", solve), ("grad", jax.grad(loss))):
                r, _, _ = _measure_program(ctx, lambda fn=fn: (compile_fn(fn, t), (t,)))
                row.update({f"{what}_{k}": v for k, v in r.items()
                            if k in ("compile_s", "ms_median", "ms_iqr", "ms_min", "gflop",
                                     "xla_peak_mib")})
            rows.append(row)
    return {"rows": rows}


# ------------------------------------------------------------------------------ RTSS baseline

def _rtss_program(ctx: Context, cameras: int):
    from gijax.baseline.rtss import RTSSConfig, _rtss
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
        return _rtss(rig, images, masks, cand, pano, config)["inv_distance"]

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
        stats = summarize(times[row["cameras"]])
        row.update(_timing_row(stats))
        row.update(_program_row(progs[row["cameras"]][0], stats.median, ctx.limits))
    out = {"rows": rows}
    if len(rows) > 1:
        out["ms_per_camera"] = linear_increment([r["cameras"] for r in rows],
                                                [r["ms_median"] for r in rows])
        first = rows[0]["cameras"]
        for row in rows[1:]:
            row[f"ratio_vs_{first}cam"] = paired_ratio(times[row["cameras"]], times[first]).median
    return out


# ------------------------------------------------------------------------------ training

def train_step(ctx: Context) -> dict:
    """One optimiser step (forward, backward, Adam) of a preset on one device."""
    from gijax.model import create_model
    from gijax.train import step as S
    from gijax.train.config import TrainConfig

    s = ctx.settings
    rows = []
    for name in s.train_presets:
        ctx.log(f"train step {name} batch {s.train_batch} ...")
        cfg = TrainConfig(preset=name, batch_size=s.train_batch)
        mc = cfg.model_config()
        rig = network_rig(builtin_rig("paper-train"), mc)
        with CaseMemory() as mem:
            t0 = time.perf_counter()
            model = create_model(mc, 0)
            tdef, _, params, rest = S.split_model(model)
            tx = S.make_optimizer(cfg)
            mesh = S.make_mesh([ctx.device])
            state = S.place_state(S.init_state(params, rest, tx), mesh)
            step = S.jit_train_step(S.build_train_step(tdef, tx, mc.loss), mesh)
            rng = np.random.default_rng(0)
            sur, masks, cand = network_inputs(mc, rig.num_cameras, s.train_batch)
            h, w = mc.output_hw
            batch = S.place_batch({
                "images": np.asarray(sur), "masks": np.asarray(masks),
                "distance": rng.uniform(0.5, 20, (s.train_batch, h, w)).astype(np.float32),
                "valid": np.ones((s.train_batch, h, w), bool)}, mesh)
            compiled = step.lower(state, batch, rig, cand).compile()
            compile_s = time.perf_counter() - t0
            holder = {"state": state}

            def one():
                holder["state"], out = compiled(holder["state"], batch, rig, cand)
                return out

            jax.block_until_ready(one())
        stats, _ = time_call(one, warmup=max(ctx.warmup - 1, 0), reps=s.train_steps)
        row = {"preset": name, "batch": s.train_batch, "compile_s": compile_s,
               **_timing_row(stats), "samples_per_s": s.train_batch / stats.median,
               **mem.result(), **_program_row(compiled, stats.median, ctx.limits)}
        rows.append(row)
    return {"rows": rows}


# ------------------------------------------------------------------------------ scaling

def scaling(ctx: Context) -> dict:
    """Forward time and memory of one preset against the camera count (regular-polygon rigs,
    1 m sides) and the candidate count; every point timed in the same alternating rounds."""
    s = ctx.settings
    base = get_preset(s.scaling_preset)
    points = [(n, base.num_candidates) for n in s.scaling_cameras]
    points += [(s.scaling_cameras[0], d) for d in s.scaling_candidates
               if (s.scaling_cameras[0], d) not in points]
    progs, rows = {}, {}
    for cams, cands in points:
        ctx.log(f"scaling {base.name}: {cams} cameras, {cands} candidates ...")
        cfg = base if cands == base.num_candidates else with_candidates(base, cands)
        rig = network_rig(polygon_rig(cams), cfg)
        with CaseMemory() as mem:
            t0 = time.perf_counter()
            compiled, args = eval_forward_program(cfg, rig)
            compile_s = time.perf_counter() - t0
            jax.block_until_ready(compiled(*args))
        progs[(cams, cands)] = (compiled, args)
        rows[(cams, cands)] = {"preset": base.name, "cameras": cams, "candidates": cands,
                               "compile_s": compile_s, **mem.result()}
    times = time_alternating({k: (lambda c=c, a=a: c(*a)) for k, (c, a) in progs.items()},
                             warmup=max(ctx.warmup - 1, 0), reps=s.scaling_reps)
    for key, row in rows.items():
        stats = summarize(times[key])
        row.update(_timing_row(stats))
        row.update(_program_row(progs[key][0], stats.median, ctx.limits))
    d0 = base.num_candidates
    cam_rows = [rows[(n, d0)] for n in s.scaling_cameras]
    cand_rows = [rows[(s.scaling_cameras[0], d)] for d in s.scaling_candidates]
    out = {"rows": list(rows.values()), "raw_ms": {f"{k[0]}cam_{k[1]}cand":
                                                    [1e3 * t for t in v]
                                                    for k, v in times.items()}}
    if len(cam_rows) > 1:
        out["ms_per_camera"] = linear_increment([r["cameras"] for r in cam_rows],
                                                [r["ms_median"] for r in cam_rows])
        out["mib_per_camera"] = linear_increment([r["cameras"] for r in cam_rows],
                                                 [r.get("xla_peak_mib", 0.0) for r in cam_rows])
        first = (s.scaling_cameras[0], d0)
        for n in s.scaling_cameras[1:]:
            rows[(n, d0)]["ratio_vs_first"] = paired_ratio(times[(n, d0)], times[first]).median
    if len(cand_rows) > 1:
        out["ms_per_candidate"] = linear_increment([r["candidates"] for r in cand_rows],
                                                   [r["ms_median"] for r in cand_rows])
        out["mib_per_candidate"] = linear_increment(
            [r["candidates"] for r in cand_rows], [r.get("xla_peak_mib", 0.0) for r in cand_rows])
    return out


CASES = {
    "forward": forward,
    "onnx": onnx_vs_jax,
    "sweep": sweep,
    "stages": stages,
    "candidates": candidates,
    "rtss": rtss,
    "train": train_step,
    "scaling": scaling,
}
