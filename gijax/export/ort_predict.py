"""Run an exported gijax ONNX file with onnxruntime (CPU, or CUDA where it is available).

:class:`OnnxPredictor` mirrors :func:`gijax.predict.predict`: raw fisheye images of one sample
in, numpy panoramas out, so ``gijax predict --backend onnx`` can use it in place of the JAX model.
The file's metadata (written by :func:`gijax.export.onnx_export.export_onnx`) tells the image
size, camera count, mode and default candidates.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from gijax.export.graph import intrinsics_layout, rig_arrays
from gijax.export.onnx_export import IMAGES, MASKS, OUTPUTS, RIG_INPUTS, read_metadata


def available_providers() -> list[str]:
    import onnxruntime as ort

    return list(ort.get_available_providers())


def default_providers() -> list[str]:
    """CUDA first when this onnxruntime has it, then the CPU."""
    have = available_providers()
    return [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in have]


def make_session(path: str, providers=None, threads: int | None = None):
    """An ``onnxruntime.InferenceSession`` for ``path`` with full graph optimisation."""
    import onnxruntime as ort

    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such ONNX file")
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3  # errors only: shape-merge notes are not actionable
    if threads:
        opts.intra_op_num_threads = int(threads)
    providers = default_providers() if providers is None else list(providers)
    unknown = [p for p in providers if p not in available_providers()]
    if unknown:
        raise ValueError(f"onnxruntime providers {unknown} are not available here; available: "
                         f"{available_providers()}")
    return ort.InferenceSession(str(path), sess_options=opts, providers=providers)


def rig_feed(run_rig, candidates) -> dict:
    """The rig inputs of a rig-as-input file: ``run_rig`` must be at the model's image size."""
    arrays = {k: np.asarray(v, np.float32) for k, v in rig_arrays(run_rig).items()}
    arrays["candidates"] = np.asarray(candidates, np.float32)
    return arrays


class OnnxPredictor:
    """An exported model: ``predict(rig, images, masks=None, candidates=None) -> dict``.

    Args:
      path: the ``.onnx`` file.
      providers: onnxruntime execution providers; default CUDA where available, else CPU.
      threads: intra-op threads (default: onnxruntime's choice).
    """

    def __init__(self, path: str | os.PathLike, providers=None, threads: int | None = None):
        import onnx

        self.path = str(path)
        self.session = make_session(self.path, providers, threads)
        self.meta = read_metadata(onnx.load(self.path, load_external_data=False))
        if "config" not in self.meta:
            raise ValueError(f"{self.path}: not a gijax export (no gijax metadata)")
        self.config = json.loads(self.meta["config"])
        self.rig_as_input = self.meta.get("mode") == "rig_as_input"
        self.candidates = np.asarray(json.loads(self.meta["candidates_m"]), np.float64)
        self.num_cameras = int(self.meta["num_cameras"])
        self.image_hw = tuple(json.loads(self.meta["image_hw"]))
        self.image_scale = float(self.meta.get("image_scale", "1.0"))
        first = self.session.get_inputs()[0]
        self.batch = first.shape[0] if isinstance(first.shape[0], int) else None

    @property
    def providers(self) -> list[str]:
        return self.session.get_providers()

    def _scaled_rig(self, rig):
        from gijax.geometry.rig import scale_rig

        cam = rig.cameras[0]
        if (cam.height, cam.width) == self.image_hw:
            return rig
        scaled = scale_rig(rig, self.image_scale)
        if (scaled.cameras[0].height, scaled.cameras[0].width) != self.image_hw:
            raise ValueError(f"{self.path}: the model takes {self.image_hw[0]} x "
                             f"{self.image_hw[1]} images; the rig's cameras are {cam.height} x "
                             f"{cam.width} (scaled by {self.image_scale}: "
                             f"{scaled.cameras[0].height} x {scaled.cameras[0].width})")
        return scaled

    def _inputs(self, rig, images, masks):
        import cv2

        images = np.asarray(images)
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"images must have shape (num_cameras, height, width, 3); found "
                             f"{images.shape}")
        if images.shape[0] != self.num_cameras or rig.num_cameras != self.num_cameras:
            raise ValueError(f"{self.path} was exported for {self.num_cameras} cameras; found "
                             f"{images.shape[0]} images and a rig with {rig.num_cameras}")
        run_rig = self._scaled_rig(rig)
        h, w = self.image_hw
        if masks is None:
            masks = np.stack([np.ones((h, w), np.float32) if m is None else np.asarray(m)
                              for m in run_rig.masks])
        masks = np.asarray(masks, np.float32)
        if masks.shape != images.shape[:3]:
            raise ValueError(f"masks must have shape {images.shape[:3]}; found {masks.shape}")
        if images.shape[1:3] != (h, w):
            if images.shape[1:3] != (rig.cameras[0].height, rig.cameras[0].width):
                raise ValueError(f"images must be {h} x {w} or the rig's {rig.cameras[0].height}"
                                 f" x {rig.cameras[0].width}; found {images.shape[1:3]}")
            images = np.stack([cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)
                               for im in images])
            masks = np.stack([cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA)
                              for m in masks])
        if np.issubdtype(images.dtype, np.integer):
            images = images.astype(np.float32) / 255.0
        return run_rig, images.astype(np.float32), masks

    def predict(self, rig, images, masks=None, candidates=None) -> dict:
        """One sample: ``images`` (N, h, w, 3) uint8 or float RGB in [0, 1] at the rig's size or
        at the model's image size; ``masks`` (N, h, w) or None for the rig's own masks;
        ``candidates`` (D,) metres (rig-as-input files only; default: the exported list).

        Returns numpy ``inv_distance``, ``distance``, ``entropy`` (H, W), ``valid`` (H, W) bool
        and ``candidates``.
        """
        run_rig, images, masks = self._inputs(rig, images, masks)
        feed = {IMAGES: images[None], MASKS: masks[None]}
        if self.batch not in (None, 1):
            feed = {k: np.repeat(v, self.batch, axis=0) for k, v in feed.items()}
        cand = self.candidates
        if candidates is not None:
            cand = np.asarray(candidates, np.float64)
            if not self.rig_as_input and not np.allclose(cand, self.candidates, rtol=1e-6):
                raise ValueError(f"{self.path} has its candidates baked in "
                                 f"({np.round(self.candidates, 4).tolist()} m); export with "
                                 f"--rig-as-input to choose candidates at run time")
            if cand.shape != self.candidates.shape:
                raise ValueError(f"{self.path} needs {len(self.candidates)} candidates; found "
                                 f"{cand.shape}")
        if self.rig_as_input:
            layout = json.loads(self.meta["intrinsics_layout"])
            if list(intrinsics_layout(run_rig)) != layout:
                raise ValueError(f"{self.path} takes {self.meta['camera_model']!r} intrinsics "
                                 f"{layout}; the rig's cameras have "
                                 f"{list(intrinsics_layout(run_rig))}")
            feed.update(rig_feed(run_rig, cand))
        names = [o.name for o in self.session.get_outputs()]
        got = dict(zip(names, self.session.run(names, feed)))
        out = {k: np.asarray(got[k][0]) for k in OUTPUTS}
        out["valid"] = out["valid"] > 0.5
        out["candidates"] = cand
        return out

    def run_batch(self, feed: dict) -> dict:
        """Raw session call: ``feed`` maps input names to arrays; returns all outputs."""
        names = [o.name for o in self.session.get_outputs()]
        return dict(zip(names, self.session.run(names, feed)))


__all__ = ["OnnxPredictor", "make_session", "rig_feed", "default_providers", "RIG_INPUTS"]
