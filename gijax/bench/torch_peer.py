"""gijax against its PyTorch twin (:mod:`gijax.bench.torch_twin`), side by side in fresh processes.

Every measurement runs in a child of its own (``python -m gijax.bench.torch_peer MODE ...``,
one JSON line on stdout), so that each figure's peak resident set belongs to one framework,
one preset, one batch size and one mode:

* ``jax``: gijax's inference (the eval-mode forward the ``forward`` case compiles,
  :func:`gijax.bench.cases.programs.eval_forward_program`, sweep grids computed from the rig
  inside) or its training step (:func:`gijax.bench.train_step.train_step_case`, timed with
  :func:`~gijax.bench.train_step.time_steps`: the number every other training benchmark
  reports);
* ``torch``: the twin on the same inputs, read from a file this module writes in the parent
  (:func:`write_inputs`: the random batch of the JAX side, gijax's own sweep grids for the
  preset's rig and candidates as normalised ``grid_sample`` coordinates, the spherical layer's
  offsets). The twin's process imports torch and numpy, never JAX (checked:
  ``imported_jax``). Training is forward, backward and ``torch.optim.Adam`` (lr 1e-4, the
  defaults optax's Adam shares) on the preset's loss.

Both sides run on the same CPUs with the same thread count (``threads``, default 2): each
child restricts itself to that many CPUs before importing its framework, and torch is told
``torch.set_num_threads``. Weights are random (gijax's initialiser on its side, PyTorch's on
the twin's); tests/test_torch_twin.py checks that the two compute the same numbers on equal
weights. The parent alternates the frameworks round by round (the first one changes every
round), each child timing ``reps`` steps after ``warmup`` untimed ones that follow the first
(compiling) call; a row pools the steps of all rounds (min / median / max) and takes the ratio
of the per-round medians.

This module imports neither JAX nor torch at the top: its children import one each.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

MODES = ("infer", "train")
FRAMEWORKS = ("gijax", "pytorch")
LEARNING_RATE = 1e-4     # the paper's Adam learning rate, TrainConfig's default

# ModelConfig fields the twin reads (from a config object, or a mapping of them).
TWIN_FIELDS = ("name", "num_candidates", "loss", "features", "cost_volume", "num_cameras",
               "feature_channels", "feature_blocks", "unet_in", "unet_base", "surrogate_hw",
               "cost_hw", "output_hw", "spherical_taps", "sweep_boundary", "output_stride",
               "refine")


def twin_config(config) -> dict:
    """The fields of a :class:`gijax.nn.presets.ModelConfig` (or a mapping of them) the twin is
    built from, JSON-ready; ValueError naming every choice the twin does not build (it builds
    the release's: ``spherical_taps='release'``, ``sweep_boundary='zeros'``, no refinement)."""
    get = config.get if isinstance(config, Mapping) else (lambda k: getattr(config, k))
    cfg = {k: get(k) for k in TWIN_FIELDS}
    for k in ("feature_blocks", "surrogate_hw", "cost_hw", "output_hw"):
        cfg[k] = [int(v) for v in cfg[k]]
    problems = []
    if cfg["features"] == "spherical" and cfg["spherical_taps"] != "release":
        problems.append(f"spherical_taps={cfg['spherical_taps']!r} (only 'release')")
    if cfg["sweep_boundary"] != "zeros":
        problems.append(f"sweep_boundary={cfg['sweep_boundary']!r} (only 'zeros')")
    if cfg["refine"]:
        problems.append("refine=True (no guided refinement)")
    if problems:
        raise ValueError(f"the PyTorch twin builds the release's network only; model "
                         f"{cfg['name']!r} has " + ", ".join(problems))
    return cfg


def check_presets(presets: Sequence[str]) -> list:
    """The :class:`~gijax.nn.presets.ModelConfig` of each name; ValueError for an unknown name
    or one the twin cannot build (:func:`twin_config`), or an empty list."""
    from gijax.nn.presets import get_preset

    if not presets:
        raise ValueError("torch-peer: no presets to time; name at least one")
    configs = [get_preset(name) for name in presets]
    for cfg in configs:
        twin_config(cfg)
    return configs


def peer_inputs(config, batch: int, seed: int = 0) -> dict[str, np.ndarray]:
    """What both frameworks are fed for ``config`` at ``batch``, as numpy arrays: the inputs of
    :func:`gijax.bench.train_step.train_step_case` (``surrogates`` (B, N, Hs, Ws, 3),
    ``masks`` (B, N, Hs, Ws), ``candidates`` (D,) metres, ``distance`` (B, H, W) labels,
    ``valid``), gijax's sweep on the training rig (``sweep_px`` (N, D, h, w, 2) feature-map
    pixels, ``grids`` the same as normalised ``grid_sample`` coordinates, ``grid_ok``) and, for
    spherical features, the release's tap ``offsets`` (hf, wf, 9, 2)."""
    from gijax.bench.rigs import network_inputs, network_rig
    from gijax.geometry.layouts import builtin_rig
    from gijax.model import model_grids
    from gijax.nn.spherical import release_offsets
    from gijax.sweep.grid import normalised_from_pixels

    rig = network_rig(builtin_rig("paper-train"), config)
    if config.cost_volume == "concat" and config.num_cameras != rig.num_cameras:
        raise ValueError(f"the benchmark rig has {rig.num_cameras} cameras; {config.name} "
                         f"needs {config.num_cameras}")
    sur, masks, cand = network_inputs(config, rig.num_cameras, batch, seed)
    grids = model_grids(config, rig, cand)
    px, ok = grids.sweep_px, grids.sweep_ok
    hf, wf = config.feature_hw
    h, w = config.output_hw
    rng = np.random.default_rng(seed)
    out = {"surrogates": np.asarray(sur), "masks": np.asarray(masks),
           "candidates": np.asarray(cand),
           "distance": rng.uniform(0.5, 20, (batch, h, w)).astype(np.float32),
           "valid": np.ones((batch, h, w), bool), "sweep_px": np.asarray(px),
           "grids": np.asarray(normalised_from_pixels(px, hf, wf)), "grid_ok": np.asarray(ok)}
    if config.features == "spherical":
        out["offsets"] = release_offsets(hf, wf).astype(np.float32)
    return out


def write_inputs(path: str | os.PathLike, config, batch: int) -> Path:
    """:func:`peer_inputs` and :func:`twin_config` of ``config`` in one ``.npz`` file."""
    path = Path(path)
    np.savez(path, twin_config=np.asarray(json.dumps(twin_config(config))),
             **peer_inputs(config, batch))
    return path


def read_inputs(path: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """(twin config, arrays) of a file written by :func:`write_inputs` (numpy only)."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    return json.loads(str(arrays.pop("twin_config"))), arrays


# ------------------------------------------------------------------------------- children

def _use_cpus(threads: int) -> int:
    """Restrict this process to ``threads`` of its CPUs (before a framework sizes its thread
    pool from them); the number it may use."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) > threads:
        os.sched_setaffinity(0, cpus[:threads])
    return len(os.sched_getaffinity(0))


def _step_row(times: Sequence[float], batch: int) -> dict:
    return {"step_s": [float(t) for t in times], "s_median": statistics.median(times),
            "samples_per_s": batch / statistics.median(times)}


def jax_child(preset: str, mode: str, batch: int, reps: int, warmup: int, threads: int) -> dict:
    row = {"framework": "gijax", "cpus": _use_cpus(threads)}
    import jax

    from gijax.bench.isolated import peak_rss_gb
    from gijax.bench.timing import time_call

    if mode == "train":
        from gijax.bench.train_step import time_steps, train_step_case

        case = train_step_case(preset, batch)
        row["build_s"] = case.compile_s
        _, times = time_call(lambda: time_steps(case, 1), warmup=warmup, reps=reps)
    else:
        from gijax.bench.cases.programs import eval_forward_program
        from gijax.bench.rigs import network_rig
        from gijax.geometry.layouts import builtin_rig
        from gijax.nn.presets import get_preset

        cfg = get_preset(preset)
        t0 = time.perf_counter()
        compiled, args = eval_forward_program(cfg, network_rig(builtin_rig("paper-train"), cfg),
                                              batch)
        jax.block_until_ready(compiled(*args))
        row["build_s"] = time.perf_counter() - t0
        _, times = time_call(lambda: compiled(*args), warmup=warmup, reps=reps)
    row.update(_step_row(times, batch), peak_gb=peak_rss_gb(), version=jax.__version__)
    return row


def torch_child(path: str, mode: str, reps: int, warmup: int, threads: int) -> dict:
    row = {"framework": "pytorch", "cpus": _use_cpus(threads)}
    import torch

    torch.set_num_threads(threads)
    from gijax.bench import torch_twin as T
    from gijax.bench.isolated import peak_rss_gb
    from gijax.bench.timing import time_call

    cfg, inputs = read_inputs(path)
    batch = inputs["surrogates"].shape[0]
    t0 = time.perf_counter()
    torch.manual_seed(0)
    twin = T.TorchTwin(cfg, inputs["candidates"], inputs.get("offsets"))
    if mode == "train":
        run = T.train_step(twin, inputs, LEARNING_RATE)
    else:
        run = T.inference(twin, inputs)
    run()
    row["build_s"] = time.perf_counter() - t0
    _, times = time_call(run, warmup=warmup, reps=reps)
    row.update(_step_row(times, batch), peak_gb=peak_rss_gb(), version=torch.__version__,
               threads=torch.get_num_threads(), imported_jax="jax" in sys.modules)
    if cfg["features"] == "spherical":
        row["spherical"] = T.SPHERICAL_BACKEND
    return row


def child_main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m gijax.bench.torch_peer",
                                description="One measurement of the PyTorch peer benchmark (see "
                                            "the module docstring); prints one JSON line.")
    sub = p.add_subparsers(dest="side", required=True)
    j = sub.add_parser("jax")
    j.add_argument("preset")
    j.add_argument("--batch", type=int, required=True)
    t = sub.add_parser("torch")
    t.add_argument("inputs", help="a file written by write_inputs")
    for q in (j, t):
        q.add_argument("--mode", choices=MODES, required=True)
        q.add_argument("--reps", type=int, default=5)
        q.add_argument("--warmup", type=int, default=1)
        q.add_argument("--threads", type=int, default=2)
    a = p.parse_args(argv)
    if a.side == "jax":
        row = jax_child(a.preset, a.mode, a.batch, a.reps, a.warmup, a.threads)
    else:
        row = torch_child(a.inputs, a.mode, a.reps, a.warmup, a.threads)
    print(json.dumps(row), flush=True)
    return 0


# ------------------------------------------------------------------------------- parent

def torch_version(python: str) -> str | None:
    """The torch version importable by the interpreter ``python``, or None."""
    try:
        proc = subprocess.run([python, "-c", "import torch; print(torch.__version__)"],
                              capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


def run_child(python: str, args: Sequence[str]) -> dict:
    """``python -m gijax.bench.torch_peer *args`` in a fresh process; its JSON row
    (:func:`gijax.bench.isolated.run_child`)."""
    from gijax.bench.isolated import run_child as run_module

    return run_module(args, module="gijax.bench.torch_peer", python=python)


def peer_row(preset: str, mode: str, batch: int, runs: Mapping[str, list[dict]]) -> dict:
    """One table row from the children's rows of both frameworks (one per round each)."""
    from gijax.bench.timing import timing_stats

    row = {"preset": preset, "mode": mode, "batch": batch, "rounds": len(runs["gijax"])}
    for fw in FRAMEWORKS:
        stats = timing_stats([t for r in runs[fw] for t in r["step_s"]])
        row.update({f"{fw}_s_min": stats.min, f"{fw}_s_median": stats.median,
                    f"{fw}_s_max": stats.max, f"{fw}_samples_per_s": batch / stats.median,
                    f"{fw}_peak_gb": max(r["peak_gb"] for r in runs[fw]),
                    f"{fw}_build_s": statistics.median(r["build_s"] for r in runs[fw]),
                    f"{fw}_version": runs[fw][0]["version"], f"{fw}_cpus": runs[fw][0]["cpus"]})
    ratios = [g["s_median"] / t["s_median"] for g, t in zip(runs["gijax"], runs["pytorch"])]
    row["gijax_over_pytorch"] = statistics.median(ratios)
    row["ratio_per_round"] = ratios
    row["pytorch_threads"] = runs["pytorch"][0]["threads"]
    row["pytorch_imported_jax"] = any(r["imported_jax"] for r in runs["pytorch"])
    if "spherical" in runs["pytorch"][0]:
        row["spherical"] = runs["pytorch"][0]["spherical"]
    return row


def measure_peers(presets: Sequence[str], batches: Sequence[int] = (8, 4),
                  modes: Sequence[str] = MODES, rounds: int = 3, reps: int = 5, warmup: int = 1,
                  threads: int = 2, torch_python: str | None = None,
                  log: Callable[[str], None] = print) -> dict:
    """Rows (preset, mode, batch) of both frameworks in alternating rounds of fresh processes
    (module docstring). ``torch_python`` is the interpreter that has torch (default: this one;
    the gijax children always use this one). Without torch there: ``{'rows': [], 'skipped':
    reason}``, the reason logged in one line. ValueError for a preset the twin cannot build,
    before anything runs."""
    python = torch_python or sys.executable
    for name, value in (("rounds", rounds), ("reps", reps), ("threads", threads)):
        if int(value) != value or value < 1:
            raise ValueError(f"torch-peer: {name} must be a positive integer; found {value!r}")
    bad_modes = [m for m in modes if m not in MODES]
    if bad_modes or not modes:
        raise ValueError(f"torch-peer: modes must be among {MODES}; found {list(modes)}")
    if not batches or any(int(b) != b or b < 1 for b in batches):
        raise ValueError(f"torch-peer: batch sizes must be positive integers; found "
                         f"{list(batches)}")
    configs = check_presets(presets)
    version = torch_version(python)
    if version is None:
        reason = (f"torch is not installed for {python}; install it there or pass "
                  f"--torch-python with an interpreter that has it")
        log(f"torch-peer: skipped: {reason}")
        return {"rows": [], "skipped": reason}
    log(f"torch-peer: torch {version} ({python}), {threads} threads each")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for cfg in configs:
            for batch in batches:
                path = write_inputs(Path(tmp) / f"{cfg.name}-b{batch}.npz", cfg, batch)
                for mode in modes:
                    common = ["--mode", mode, "--reps", reps, "--warmup", warmup,
                              "--threads", threads]
                    runs = {fw: [] for fw in FRAMEWORKS}
                    for r in range(rounds):
                        for fw in (FRAMEWORKS if r % 2 == 0 else FRAMEWORKS[::-1]):
                            if fw == "gijax":
                                got = run_child(sys.executable, ["jax", cfg.name, "--batch",
                                                                 batch, *common])
                            else:
                                got = run_child(python, ["torch", path, *common])
                            runs[fw].append(got)
                            log(f"torch-peer {cfg.name} {mode} batch {batch} round {r + 1}/"
                                f"{rounds} {fw}: {got['s_median']:.3f} s/step, peak "
                                f"{got['peak_gb']:.2f} GB")
                    rows.append(peer_row(cfg.name, mode, batch, runs))
    out = {"rows": rows, "torch": version, "torch_python": python, "threads": threads}
    spherical = {r["spherical"] for r in rows if "spherical" in r}
    if spherical:
        out["spherical"] = sorted(spherical)
    return out


if __name__ == "__main__":
    raise SystemExit(child_main())
