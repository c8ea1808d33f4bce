"""The benchmark suite: settings per suite, the runner, and the Markdown report.

``quick`` uses the CPU-size networks (128 x 512 surrogates, 32 x 128 output) and small
baseline images and runs in a few minutes on a 2-core CPU; ``full`` uses the paper's sizes
(512 x 2048 surrogates, 160 x 640 output, 1024 x 1024 fisheye images) and is meant for a GPU.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable, Sequence

import jax

from gijax.bench import cases as C
from gijax.bench.machine import load_average, machine_info
from gijax.bench.report import markdown_table, text_table, write_json, write_text

PAPER_PRESETS = ("E8", "G8", "E16", "G16", "G16V", "G16V-released", "G16VV")
# The distinct -cpu networks and losses, timed against the PyTorch twin by the torch-peer case:
# E8 / G8 and E16 / G16 differ only in their candidates; G16 and G16V share a network but not
# a loss (smooth L1, volume).
TORCH_PEER_PRESETS = ("G8-cpu", "G16-cpu", "G16V-cpu", "G16V-released-cpu", "G16VV-cpu")


@dataclasses.dataclass(frozen=True)
class SuiteSettings:
    name: str
    presets: tuple
    sweep_preset: str
    onnx_presets: tuple
    candidate_rigs: tuple
    candidate_counts: tuple
    rtss_scale: float
    rtss_match: int
    rtss_pano: tuple
    rtss_candidates: int
    rtss_cameras: tuple
    train_presets: tuple
    train_batch: int
    train_steps: int
    scaling_preset: str
    scaling_cameras: tuple
    scaling_candidates: tuple
    isolated_presets: tuple = ()
    precision_presets: tuple = ("G16VV-cpu",)
    precision_calibration: int = 2
    torch_presets: tuple = TORCH_PEER_PRESETS
    torch_batches: tuple = (8, 4)
    torch_modes: tuple = ("infer", "train")
    torch_rounds: int = 3
    torch_threads: int = 2
    torch_python: str | None = None
    reps: int = 5
    warmup: int = 1
    scaling_reps: int = 10
    matmul_n: int = 1024
    bandwidth_mib: int = 128


SUITES = {
    "quick": SuiteSettings(
        name="quick", presets=tuple(p + "-cpu" for p in PAPER_PRESETS),
        sweep_preset="G16VV-cpu", onnx_presets=("G16VV-cpu",),
        candidate_rigs=("paper-test2",), candidate_counts=(16,),
        rtss_scale=0.125, rtss_match=128, rtss_pano=(40, 160), rtss_candidates=32,
        rtss_cameras=(3, 4), train_presets=("G16VV-cpu",), train_batch=2, train_steps=3,
        scaling_preset="G16VV-cpu", scaling_cameras=(3, 4, 5), scaling_candidates=(8, 16, 32),
        isolated_presets=tuple(p + "-cpu" for p in PAPER_PRESETS) + ("G16VV-cpu-plain",),
        reps=5, warmup=1, matmul_n=1024, bandwidth_mib=128),
    "full": SuiteSettings(
        name="full", presets=PAPER_PRESETS, sweep_preset="G16VV",
        onnx_presets=("G16V-released", "G16VV"),
        candidate_rigs=("paper-test2", "paper-test3"), candidate_counts=(8, 16, 32),
        rtss_scale=1.0, rtss_match=512, rtss_pano=(160, 640), rtss_candidates=32,
        rtss_cameras=(3, 4, 5), train_presets=("G16VV",), train_batch=2, train_steps=5,
        scaling_preset="G16VV", scaling_cameras=(3, 4, 5), scaling_candidates=(8, 16, 32),
        isolated_presets=PAPER_PRESETS + ("G16VV-plain",),
        precision_presets=("G16VV-cpu", "G16VV"), precision_calibration=1,
        reps=10, warmup=2, scaling_reps=20, matmul_n=4096, bandwidth_mib=1024),
}
# On a GPU the calibration needs bigger problems to reach the device's limits.
GPU_CALIBRATION = {"matmul_n": 8192, "bandwidth_mib": 2048}

CASE_ORDER = ("forward", "stages", "onnx", "sweep", "candidates", "rtss", "train", "train-stages",
              "scaling", "isolated", "precision", "torch-peer")
# 'isolated' spawns fresh processes per preset and exports every network, 'precision' exports
# and runs three files per preset in fresh processes, 'torch-peer' spawns fresh processes per
# preset, mode, batch, framework and round: they run when asked.
ON_REQUEST = ("isolated", "precision", "torch-peer")
DEFAULT_CASES = tuple(c for c in CASE_ORDER if c not in ON_REQUEST)


def select_device(kind: str):
    """The first JAX device of ``kind`` ('cpu' or 'gpu'); ValueError when there is none."""
    if kind not in ("cpu", "gpu"):
        raise ValueError(f"--device must be 'cpu' or 'gpu'; found {kind!r}")
    try:
        devices = jax.devices(kind)
    except RuntimeError:
        devices = []
    if not devices:
        raise ValueError(f"--device {kind}: JAX sees no {kind.upper()} (devices: "
                         f"{jax.devices()}); install a CUDA build of jaxlib or use --device cpu")
    return devices[0]


def settings_for(suite: str, device, reps: int | None = None,
                 warmup: int | None = None) -> SuiteSettings:
    if suite not in SUITES:
        raise ValueError(f"--suite must be one of {sorted(SUITES)}; found {suite!r}")
    s = SUITES[suite]
    if device.platform != "cpu":
        s = dataclasses.replace(s, **GPU_CALIBRATION)
    if reps is not None:
        if reps < 1:
            raise ValueError(f"--reps must be >= 1; found {reps}")
        s = dataclasses.replace(s, reps=reps, scaling_reps=max(reps, 2))
    if warmup is not None:
        if warmup < 0:
            raise ValueError(f"--warmup must be >= 0; found {warmup}")
        s = dataclasses.replace(s, warmup=warmup)
    return s


def run_suite(suite: str = "quick", device: str = "cpu", out_dir: str | Path = "bench-out",
              cases: Sequence[str] | None = None, reps: int | None = None,
              warmup: int | None = None, log: Callable[[str], None] = print,
              overrides: dict | None = None) -> dict:
    """Run the calibration and the chosen cases (default all but :data:`ON_REQUEST`), write
    ``bench.json``, ``bench.md`` and (with the scaling case) ``scaling.png`` to ``out_dir``;
    returns the result dict. ``overrides`` replaces fields of the suite's
    :class:`SuiteSettings` (e.g. ``torch_presets``)."""
    chosen = list(DEFAULT_CASES) if not cases else list(cases)
    unknown = [c for c in chosen if c not in C.CASES]
    if unknown:
        raise ValueError(f"unknown case(s) {unknown}; choose from {list(CASE_ORDER)}")
    dev = select_device(device)
    settings = settings_for(suite, dev, reps, warmup)
    if overrides:
        fields = {f.name for f in dataclasses.fields(SuiteSettings)}
        bad = sorted(set(overrides) - fields)
        if bad:
            raise ValueError(f"unknown suite setting(s) {bad}; valid: {sorted(fields)}")
        settings = dataclasses.replace(settings, **overrides)
    if {"train", "train-stages"} & set(chosen):
        # Before the first case runs: a bad preset or batch is an error now, not after the
        # calibration and the cases before.
        from gijax.nn.presets import get_preset

        for name in settings.train_presets:
            get_preset(name)
        if settings.train_batch < 1:
            raise ValueError(f"--train-batch must be at least 1; found {settings.train_batch}")
    if "torch-peer" in chosen:
        # Before the first case runs: a preset the twin cannot build is an error now.
        from gijax.bench.torch_peer import check_presets

        check_presets(settings.torch_presets)
    out_dir = Path(out_dir)
    t_start = time.perf_counter()
    result = {"suite": suite, "settings": dataclasses.asdict(settings),
              "machine": machine_info(dev), "cases": {}, "durations_s": {}}
    with jax.default_device(dev):
        ctx = C.Context(settings, dev, log=log)
        t0 = time.perf_counter()
        result["calibration"] = C.calibrate(ctx)
        result["durations_s"]["calibration"] = time.perf_counter() - t0
        for name in CASE_ORDER:
            if name not in chosen:
                continue
            t0 = time.perf_counter()
            result["cases"][name] = C.CASES[name](ctx)
            result["durations_s"][name] = time.perf_counter() - t0
            log(f"  {name}: {result['durations_s'][name]:.1f} s")
    result["total_s"] = time.perf_counter() - t_start
    result["load_average_end"] = load_average()
    if "scaling" in result["cases"]:
        from gijax.bench.plots import scaling_figure

        scaling_figure(result["cases"]["scaling"], out_dir / "scaling.png",
                       rtss=result["cases"].get("rtss"))
        result["figures"] = ["scaling.png"]
    write_json(out_dir / "bench.json", result)
    write_text(out_dir / "bench.md", render_markdown(result))
    return result


# ------------------------------------------------------------------------------ report

def _pct(v) -> str:
    return f"{100 * v:.1f}%"


def _mem_col(rows) -> list:
    """Device peak on a GPU, RSS growth on the CPU."""
    if any(r.get("device_peak_mib") is not None for r in rows):
        return [("device peak MiB", "device_peak_mib", ".0f")]
    return [("RSS +MiB", "rss_growth_mib", ".0f")]


EFF_COLS = [("GFLOP", "gflop", ".3g"), ("GFLOP/s", "gflops_per_s", ".1f"),
            ("% peak FLOP/s", "frac_peak_flops", _pct), ("GB moved", "gbytes", ".3g"),
            ("% bandwidth", "frac_bandwidth", _pct), ("roofline ms", "roofline_s",
                                                     lambda v: f"{1e3 * v:.2f}")]
TIME_COLS = [("median ms", "ms_median", ".1f"), ("IQR ms", "ms_iqr", ".1f"),
             ("min ms", "ms_min", ".1f")]


ISOLATED_COLS = [("preset", "preset"), ("same network as", "same_as"), *[(f"{k} s", f"{k}_s", ".3f") for k in (
    "features", "sweep", "cost_volume", "unet", "regress")], ("sum s", "sum_s", ".3f"),
    ("whole s", "whole_s", ".3f"), ("whole / sum", "whole_over_sum", ".2f"),
    ("JAX peak GB", "peak_gb", ".2f"), ("PyTorch s", "pytorch_s", ".1f"),
    ("PyTorch GB", "pytorch_peak_gb", ".2f"), ("ONNX MB", "onnx_mb", ".0f"),
    ("ORT s", "ort_default_s", ".2f"), ("ORT GB", "ort_default_peak_gb", ".2f"),
    ("ORT lean s", "ort_lean_s", ".2f"), ("ORT lean GB", "ort_lean_peak_gb", ".2f"),
    ("ORT low s", "ort_low_s", ".2f"), ("ORT low GB", "ort_low_peak_gb", ".2f")]


PRECISION_COLS = [
    ("preset", "preset"), ("file", "precision"), ("MB", "onnx_mb", ".1f"),
    ("ORT s", "ort_s", ".3f"), ("speed-up vs fp32", "speedup_vs_fp32", ".2f"),
    ("ORT peak GB", "peak_gb", ".2f"), ("peak vs fp32", "peak_vs_fp32", ".2f"),
    ("session s", "session_s", ".2f"), ("export s", "export_s", ".1f"),
    ("export peak GB", "peak_gb_export", ".2f")]


TORCH_PEER_COLS = [
    ("preset", "preset"), ("mode", "mode"), ("batch", "batch"),
    ("gijax min s", "gijax_s_min", ".3f"), ("gijax median s", "gijax_s_median", ".3f"),
    ("gijax max s", "gijax_s_max", ".3f"), ("PyTorch min s", "pytorch_s_min", ".3f"),
    ("PyTorch median s", "pytorch_s_median", ".3f"), ("PyTorch max s", "pytorch_s_max", ".3f"),
    ("gijax samples/s", "gijax_samples_per_s", ".2f"),
    ("PyTorch samples/s", "pytorch_samples_per_s", ".2f"),
    ("gijax / PyTorch", "gijax_over_pytorch", ".2f"),
    ("gijax peak GB", "gijax_peak_gb", ".2f"), ("PyTorch peak GB", "pytorch_peak_gb", ".2f"),
    ("spherical layer", "spherical")]


def case_tables(result: dict) -> list[tuple[str, list, list]]:
    """(title, rows, columns) of every table of the report, in order; a case that was skipped
    has its title (saying why) and no columns."""
    cases = result["cases"]
    out = [("Calibration (limits measured in this run)", result["calibration"]["rows"],
            [("what", "what"), ("median ms", "ms_median", ".2f"), ("min ms", "ms_min", ".2f"),
             ("GFLOP/s", "gflops_per_s", ".1f"), ("GB/s", "gbytes_per_s", ".1f"),
             ("check", "check")])]
    if "forward" in cases:
        rows = cases["forward"]["rows"]
        out.append(("Forward pass per preset (batch 1, 3 cameras, surrogates in, eval mode)",
                    rows, [("preset", "preset"), ("same network as", "same_as"),
                           ("surrogate", "surrogate"), ("output", "output"), *TIME_COLS,
                           ("compile s", "compile_s", ".1f"), *EFF_COLS,
                           ("XLA peak MiB", "xla_peak_mib", ".0f"), *_mem_col(rows)]))
    if "stages" in cases:
        out.append(("Forward pass by stage (each compiled and timed alone)",
                    cases["stages"]["rows"],
                    [("preset", "preset"), ("stage", "stage"), ("output", "output"), *TIME_COLS,
                     ("share", "share", _pct), *EFF_COLS,
                     ("XLA peak MiB", "xla_peak_mib", ".0f")]))
    if "train-stages" in cases:
        rows = cases["train-stages"]["rows"]
        batch = rows[0]["batch"] if rows else "?"
        out.append((f"Training step by stage (batch {batch}, training mode; each stage's forward, "
                    "and its forward and backward, compiled and timed alone)", rows,
                    [("preset", "preset"), ("stage", "stage"), ("direction", "direction"),
                     *TIME_COLS, ("backward ms", "backward_ms", ".1f"),
                     ("share", "share", _pct), *EFF_COLS,
                     ("XLA peak MiB", "xla_peak_mib", ".0f")]))
    if "onnx" in cases:
        rows = cases["onnx"]["rows"]
        out.append(("JAX vs onnxruntime (same exported function, raw images in, alternating)",
                    rows, [("preset", "preset"), ("provider", "provider"),
                           ("JAX ms", "jax_ms_median", ".1f"), ("JAX IQR", "jax_ms_iqr", ".1f"),
                           ("ORT ms", "ort_ms_median", ".1f"), ("ORT IQR", "ort_ms_iqr", ".1f"),
                           ("JAX/ORT", "ratio_jax_over_ort", ".2f"),
                           ("ratio IQR", "ratio_iqr"),
                           ("JAX % peak", "frac_peak_flops", _pct),
                           ("ORT % peak", "ort_frac_peak_flops", _pct),
                           ("JAX XLA MiB", "xla_peak_mib", ".0f"),
                           ("JAX RSS +MiB", "jax_rss_growth_mib", ".0f"),
                           ("ORT RSS +MiB", "ort_rss_growth_mib", ".0f"),
                           ("max abs diff 1/m", "max_abs_diff_inv_distance", ".1e")]))
    if "sweep" in cases:
        rows = cases["sweep"]["rows"]
        out.append(("Sphere sweep alone (grids + sampling of features and masks)", rows,
                    [("preset", "preset"), ("volume NxDxhxwxC", "volume"), *TIME_COLS,
                     *EFF_COLS, ("least GB", "min_gbytes", ".3g"),
                     ("least-traffic ms", "bandwidth_bound_ms", ".2f"),
                     ("XLA peak MiB", "xla_peak_mib", ".0f")]))
    if "candidates" in cases:
        out.append(("Rig-aware GI candidates: solve and gradient w.r.t. camera positions",
                    cases["candidates"]["rows"],
                    [("rig", "rig"), ("cameras", "cameras"), ("n", "n"),
                     ("solve ms", "solve_ms_median", ".2f"), ("solve IQR", "solve_ms_iqr", ".2f"),
                     ("grad ms", "grad_ms_median", ".2f"), ("grad IQR", "grad_ms_iqr", ".2f"),
                     ("solve compile s", "solve_compile_s", ".1f"),
                     ("grad compile s", "grad_compile_s", ".1f")]))
    if "rtss" in cases:
        rows = cases["rtss"]["rows"]
        out.append(("Classical RTSS baseline (alternating over camera counts)", rows,
                    [("cameras", "cameras"), ("candidates", "candidates"), ("image", "image"),
                     ("match", "match"), ("panorama", "pano"), *TIME_COLS,
                     ("ratio vs first", "ratio_vs_3cam", ".2f"),
                     ("compile s", "compile_s", ".1f"), *EFF_COLS,
                     ("XLA peak MiB", "xla_peak_mib", ".0f"), *_mem_col(rows)]))
    if "train" in cases:
        rows = cases["train"]["rows"]
        out.append(("Training step (forward + backward + Adam, one device)", rows,
                    [("preset", "preset"), ("batch", "batch"), *TIME_COLS,
                     ("samples/s", "samples_per_s", ".2f"), ("compile s", "compile_s", ".1f"),
                     *EFF_COLS, ("XLA peak MiB", "xla_peak_mib", ".0f"), *_mem_col(rows)]))
    if "isolated" in cases:
        rows = cases["isolated"]["rows"]
        out.append(("Each preset in fresh processes: JAX whole forward and stages (surrogates "
                    "in), onnxruntime on the exported file (raw fisheyes in, a process without "
                    "JAX); peak resident set per process", rows, ISOLATED_COLS))
    if "precision" in cases:
        prec = cases["precision"]
        title = ("onnxruntime (CPU) on the fp32, fp16-plan and int8 files of each preset "
                 "(random weights, int8 calibrated on "
                 f"{prec.get('calibration_scenes')} rendered scene(s)); a fresh process per "
                 "file, peak resident set per process")
        if prec.get("skipped"):
            out.append((title + f": skipped, {prec['skipped']}", [], []))
        else:
            out.append((title, prec["rows"], PRECISION_COLS))
    if "torch-peer" in cases:
        peer = cases["torch-peer"]
        title = ("gijax vs its PyTorch twin (fresh process per measurement, frameworks "
                 "alternating, same threads; s per step min / median / max over all rounds)")
        if peer.get("skipped"):
            # One line, no table.
            out.append((title + f": skipped, {peer['skipped']}", [], []))
        else:
            out.append((title, peer["rows"], TORCH_PEER_COLS))
    if "scaling" in cases:
        rows = sorted(cases["scaling"]["rows"], key=lambda r: (r["cameras"], r["candidates"]))
        out.append(("Scaling with cameras and candidates (polygon rigs, 1 m sides, alternating)",
                    rows, [("preset", "preset"), ("cameras", "cameras"),
                           ("candidates", "candidates"), *TIME_COLS,
                           ("ratio vs 3 cams", "ratio_vs_first", ".2f"), *EFF_COLS,
                           ("XLA peak MiB", "xla_peak_mib", ".0f")]))
    return out


def increments(result: dict) -> list[str]:
    """One line per fitted increment (ms per camera, ms per candidate, MiB per camera)."""
    lines = []
    sc = result["cases"].get("scaling", {})
    rt = result["cases"].get("rtss", {})
    for label, d, unit in ((f"{sc.get('rows', [{}])[0].get('preset', '')} time per added camera",
                            sc.get("ms_per_camera"), "ms"),
                           ("its memory per added camera", sc.get("mib_per_camera"), "MiB"),
                           ("its time per added candidate", sc.get("ms_per_candidate"), "ms"),
                           ("its memory per added candidate", sc.get("mib_per_candidate"), "MiB"),
                           ("RTSS time per added camera", rt.get("ms_per_camera"), "ms")):
        if d:
            steps = ", ".join(f"{s:+.2f}" for s in d["steps"])
            lines.append(f"- {label}: {d['slope']:+.2f} {unit} (least-squares slope over "
                         f"{d['counts']}; successive steps per unit: {steps})")
    return lines


def render_markdown(result: dict) -> str:
    m = result["machine"]
    v = m["versions"]
    git = m["git"]
    lines = [f"# gijax benchmark: {result['suite']} suite on {m['backend']}", "",
             f"- machine: {m['cpu']} ({m['cpu_count']} logical CPUs, {m['memory_gib']} GiB), "
             f"device {m['device']}, {m['platform']}",
             f"- load average at start {m['load_average']}, at end "
             f"{result.get('load_average_end')}",
             f"- versions: python {v['python']}, jax {v['jax']}, jaxlib {v['jaxlib']}, flax "
             f"{v['flax']}, onnxruntime {v['onnxruntime']}, numpy {v['numpy']}",
             f"- git revision {git['commit']}" + (" (with uncommitted changes)"
                                                  if git.get("dirty") else ""),
             f"- {result['settings']['reps']} timed repetitions after "
             f"{result['settings']['warmup']} warm-up ({result['settings']['scaling_reps']} "
             "rounds for the scaling curves); times are medians with the inter-quartile "
             "range (IQR); comparisons alternate their contenders round by round",
             f"- wall time of the whole run: {result['total_s']:.0f} s ("
             + ", ".join(f"{k} {s:.0f} s" for k, s in result["durations_s"].items()) + ")",
             "- efficiency: FLOPs and bytes from XLA's cost analysis of the compiled program; "
             "% peak FLOP/s against the matmul calibration, % bandwidth against the copy/sum "
             "calibration; roofline ms = max(FLOPs / peak, bytes / bandwidth)", ""]
    for title, rows, cols in case_tables(result):
        lines += [f"## {title}", ""] + ([markdown_table(rows, cols), ""] if cols else [])
    inc = increments(result)
    if inc:
        lines += ["## Increments", ""] + inc + [""]
    if result.get("figures"):
        lines += [f"![scaling curves]({f})" for f in result["figures"]] + [""]
    return "\n".join(lines)


def print_summary(result: dict, log: Callable[[str], None] = print) -> None:
    for title, rows, cols in case_tables(result):
        log(f"\n{title}")
        if cols:
            log(text_table(rows, cols))
    for line in increments(result):
        log(line)


def add_arguments(parser) -> None:
    """The suite's command-line options (shared by ``gijax bench`` and benchmarks/run_suite.py)."""
    parser.add_argument("--suite", choices=sorted(SUITES), default="quick",
                        help="quick: CPU-size networks, a few minutes on 2 cores; full: the "
                             "paper's sizes (meant for a GPU)")
    parser.add_argument("--device", choices=("cpu", "gpu"), default="cpu",
                        help="run on the CPU or the first GPU JAX sees (default: cpu)")
    parser.add_argument("--out", default="bench-out",
                        help="output folder for bench.json, bench.md and scaling.png "
                             "(default: bench-out)")
    parser.add_argument("--cases", nargs="+", choices=CASE_ORDER, default=None,
                        metavar="CASE",
                        help=f"run only these cases (default: {', '.join(DEFAULT_CASES)}; "
                             "'isolated' measures every preset of the suite in fresh processes, "
                             "JAX and onnxruntime, with each process's peak memory; "
                             "'precision' runs the fp32, fp16 and int8 files in onnxruntime, "
                             "fresh processes; "
                             "'torch-peer' times gijax against its PyTorch twin, inference "
                             "and training step, in fresh processes; these three run only when "
                             "named); the calibration always runs")
    parser.add_argument("--reps", type=int, default=None,
                        help="timed repetitions per measurement (default: the suite's)")
    parser.add_argument("--warmup", type=int, default=None,
                        help="untimed warm-up calls (default: the suite's)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    train = parser.add_argument_group("train and train-stages cases")
    train.add_argument("--train-presets", nargs="+", default=None, metavar="PRESET",
                       help="presets whose training step is timed; train-stages cuts the first "
                            "into its stages (default: G16VV-cpu quick, G16VV full)")
    train.add_argument("--train-batch", type=int, default=None, metavar="B",
                       help="batch of the training step (default: 2)")
    prec = parser.add_argument_group("precision case")
    prec.add_argument("--precision-presets", nargs="+", default=None, metavar="PRESET",
                      help="presets whose fp32 / fp16 / int8 files are timed (default: "
                           "G16VV-cpu in the quick suite, G16VV-cpu G16VV in the full one)")
    prec.add_argument("--precision-calibration", type=int, default=None, metavar="SCENES",
                      help="rendered scenes the int8 file is calibrated on (default: 2 "
                           "quick, 1 full)")
    peer = parser.add_argument_group("torch-peer case")
    peer.add_argument("--torch-presets", nargs="+", default=None, metavar="PRESET",
                      help=f"presets to time (default: {' '.join(TORCH_PEER_PRESETS)}; paper "
                           "presets are slow: use them with --torch-modes infer)")
    peer.add_argument("--torch-batches", nargs="+", type=int, default=None, metavar="B",
                      help="batch sizes (default: 8 4)")
    peer.add_argument("--torch-modes", nargs="+", choices=("infer", "train"), default=None,
                      help="inference (eval-mode forward) and / or training step (default: "
                           "both)")
    peer.add_argument("--torch-rounds", type=int, default=None,
                      help="alternating rounds, a fresh process per framework each "
                           "(default: 3); each times --reps steps after --warmup")
    peer.add_argument("--torch-threads", type=int, default=None,
                      help="CPU threads of either framework (default: 2)")
    peer.add_argument("--torch-python", default=None, metavar="PYTHON",
                      help="interpreter that has torch for the PyTorch processes (default: "
                           "the one running the suite)")


def run_from_args(args) -> int:
    log = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    peer = {"torch_presets": args.torch_presets, "torch_batches": args.torch_batches,
            "torch_modes": args.torch_modes, "torch_rounds": args.torch_rounds,
            "torch_threads": args.torch_threads, "torch_python": args.torch_python,
            "precision_presets": args.precision_presets,
            "precision_calibration": args.precision_calibration,
            "train_presets": args.train_presets, "train_batch": args.train_batch}
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in peer.items()
                 if v is not None}
    result = run_suite(args.suite, args.device, args.out, args.cases, args.reps, args.warmup,
                       log=log, overrides=overrides)
    print_summary(result)
    print(f"\n{result['suite']} suite: {result['total_s']:.0f} s; wrote "
          f"{Path(args.out) / 'bench.json'} and {Path(args.out) / 'bench.md'}")
    return 0
