"""Loader throughput: batches/s and samples/s from PNG files on disk to surrogate batches.

Two sizes: the -cpu presets' (paper-train rig scaled by 0.25 -> 256 x 256 fisheyes, surrogates
128 x 512, labels 32 x 128) and the paper's (1024 x 1024 fisheyes, 512 x 2048 surrogates,
160 x 640 labels). The dataset is written to a temporary folder first, with textured images
(smooth patterns plus sensor-like noise, so PNG decoding costs what real renders cost). The
first batch (jit compilation) is excluded from the timing. Besides the rate, the CPU seconds
the loader burns per batch (all its threads): on a 2-core machine that is time taken from the
training step running beside it.

    python benchmarks/bench_loader.py [--workers 2] [--batches 6] [--cpu-batch 4]
                                      [--paper-batch 2] [--augment photometric+body] [--out PATH]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from gijax.data.loader import Loader  # noqa: E402
from gijax.data.reader import DatasetReader  # noqa: E402
from gijax.data.writer import write_dataset  # noqa: E402
from gijax.geometry.layouts import builtin_rig  # noqa: E402
from gijax.geometry.panorama import Panorama  # noqa: E402
from gijax.geometry.rig import scale_rig  # noqa: E402
from gijax.io.paths import write_json_atomic  # noqa: E402


def _cpu_preset_sizes() -> dict:
    """Surrogate and label sizes of the -cpu presets (from gijax.nn.presets when present)."""
    try:
        from gijax.nn.presets import get_preset

        cfg = get_preset("G16VV-cpu")
        return {"scale": cfg.image_scale, "surrogate": tuple(cfg.surrogate_hw),
                "label": tuple(cfg.output_hw)}
    except ImportError:
        return {"scale": 0.25, "surrogate": (128, 512), "label": (32, 128)}


def textured_sample(rig, pano: Panorama, i: int) -> dict:
    rng = np.random.default_rng(i)
    h, w = rig.cameras[0].height, rig.cameras[0].width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32) / max(h, w)
    images, dists = [], []
    for c in range(rig.num_cameras):
        f = rng.uniform(5, 40, 3)
        base = np.stack([np.sin(f[k] * xx + 3 * np.cos(f[(k + 1) % 3] * yy)) for k in range(3)], -1)
        img = 127 + 90 * base + rng.normal(0, 4, (h, w, 3))
        images.append(np.clip(img, 0, 255).astype(np.uint8))
        dists.append((2.0 + 30.0 * (xx + yy) + rng.uniform(0, 0.01, (h, w))).astype(np.float32))
    pd = (1.0 + 50.0 * rng.random()) * np.ones(pano.shape, np.float32)
    return {"images": np.stack(images), "distances": np.stack(dists),
            "masks": np.stack([np.asarray(m > 0.5, np.uint8) for m in rig.masks]),
            "pano_distance": pd}


def bench(name: str, rig, surrogate: Panorama, label: Panorama, samples: int, batch: int,
          batches: int, workers: int, tmp: Path, augment: str = "none") -> dict:
    from gijax.data.augment import augment_preset

    root = tmp / name
    t0 = time.perf_counter()
    write_dataset(root, lambda i: textured_sample(rig, label, i), rig, label, num_samples=samples)
    write_s = time.perf_counter() - t0
    reader = DatasetReader(root)
    with Loader(reader, batch_size=batch, seed=0, surrogate=surrogate, workers=workers,
                mask_augmentation=True, prefetch=2, augment=augment_preset(augment)) as loader:
        t0 = time.perf_counter()
        next(loader)
        first = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(batches):
            next(loader)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    cam = rig.cameras[0]
    return {"size": name, "fisheye": f"{cam.width}x{cam.height}",
            "surrogate": f"{surrogate.width}x{surrogate.height}",
            "label": f"{label.width}x{label.height}", "batch_size": batch, "workers": workers,
            "augment": augment, "batches_per_s": batches / dt,
            "cpu_s_per_batch": cpu / batches, "samples_per_s": batches * batch / dt,
            "first_batch_s": first, "write_samples_per_s": samples / write_s}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2,
                    help="loader threads preparing batches")
    ap.add_argument("--batches", type=int, default=6, help="timed batches per size")
    ap.add_argument("--cpu-batch", type=int, default=4, help="batch size at the -cpu size")
    ap.add_argument("--paper-batch", type=int, default=2, help="batch size at the paper size")
    ap.add_argument("--augment", default="none",
                    help="augmentation preset of the training loader (gijax.data.augment), "
                         "e.g. photometric+body")
    ap.add_argument("--out", default="benchmarks/out/bench_loader.json",
                    help="where the JSON results are written")
    args = ap.parse_args(argv)
    cpu = _cpu_preset_sizes()
    paper_rig = builtin_rig("paper-train")
    cpu_rig = scale_rig(paper_rig, cpu["scale"])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        rows.append(bench("cpu-preset", cpu_rig, Panorama.hemisphere(*cpu["surrogate"]),
                          Panorama.hemisphere(*cpu["label"]), samples=4 * args.cpu_batch,
                          batch=args.cpu_batch,
                          batches=args.batches, workers=args.workers, tmp=Path(tmp),
                          augment=args.augment))
        rows.append(bench("paper", paper_rig, Panorama.hemisphere(512, 2048),
                          Panorama.hemisphere(160, 640), samples=4 * args.paper_batch,
                          batch=args.paper_batch,
                          batches=max(2, args.batches // 2), workers=args.workers,
                          tmp=Path(tmp), augment=args.augment))
    header = f"{'size':<11}{'fisheye':>10}{'surrogate':>11}{'batch':>6}{'batches/s':>11}" \
             f"{'samples/s':>11}{'CPU s/batch':>12}{'1st batch s':>12}{'write/s':>9}"
    print(header)
    for r in rows:
        print(f"{r['size']:<11}{r['fisheye']:>10}{r['surrogate']:>11}{r['batch_size']:>6}"
              f"{r['batches_per_s']:>11.2f}{r['samples_per_s']:>11.2f}{r['cpu_s_per_batch']:>12.2f}"
              f"{r['first_batch_s']:>12.2f}"
              f"{r['write_samples_per_s']:>9.2f}")
    out = write_json_atomic(args.out, {"benchmark": "loader", "cpu_count": os.cpu_count(),
                                       "rows": rows})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
