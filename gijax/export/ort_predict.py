"""Run an exported gijax ONNX file with onnxruntime (CPU, or CUDA where it is available).

:class:`OnnxPredictor` is a :class:`gijax.evaluate.prediction.Predictor` like
:class:`gijax.predict.LearnedPredictor`: raw fisheye images of one sample in, a
:class:`~gijax.evaluate.prediction.Prediction` of numpy panoramas out, so ``gijax predict
--backend onnx`` can use it in place of the JAX model.
The file's metadata (written by :func:`gijax.export.onnx_export.export_onnx`) tells the image
size, camera count, mode and default candidates.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from gijax.evaluate.prediction import Prediction
from gijax.export.graph import intrinsics_layout, rig_arrays
from gijax.export.ort_session import (MEMORY_PROFILES, available_providers,  # noqa: F401
                                      default_providers, make_session)
from gijax.export.onnx_export import (IMAGES, MASKS, OUTPUTS, RIG_INPUTS, export_panorama,
                                      read_metadata)


def rig_feed(run_rig, candidates) -> dict:
    """The rig inputs of a rig-as-input file: ``run_rig`` must be at the model's image size."""
    arrays = {k: np.asarray(v, np.float32) for k, v in rig_arrays(run_rig).items()}
    arrays["candidates"] = np.asarray(candidates, np.float32)
    return arrays


class ExportInfo:
    """What a gijax ONNX file's metadata says (image size, cameras, mode, default candidates)
    and how to turn one sample into its input feed; shared by onnxruntime and TensorRT runs."""

    def __init__(self, path: str | os.PathLike):
        import onnx

        self.path = str(path)
        if not Path(self.path).is_file():
            raise FileNotFoundError(f"{self.path}: no such ONNX file")
        self.meta = read_metadata(onnx.load(self.path, load_external_data=False))
        if "config" not in self.meta:
            raise ValueError(f"{self.path}: not a gijax export (no gijax metadata)")
        self.config = json.loads(self.meta["config"])
        self.rig_as_input = self.meta.get("mode") == "rig_as_input"
        self.candidates = np.asarray(json.loads(self.meta["candidates_m"]), np.float64)
        self.num_cameras = int(self.meta["num_cameras"])
        self.image_hw = tuple(json.loads(self.meta["image_hw"]))
        self.image_scale = float(self.meta.get("image_scale", "1.0"))
        from gijax.store.configs import model_config_from_dict

        self.panorama = export_panorama(self.meta, model_config_from_dict(self.config))
        pano_doc = json.loads(self.meta.get("panorama", "{}"))
        # The panorama-to-rig rotation baked into the grids (identity in older files).
        self.panorama_rotation = np.asarray(pano_doc.get("rotation_panorama_to_rig", np.eye(3)),
                                            np.float64)

    def oriented_rig(self, rig):
        """``rig`` with the panorama frame the file was exported with."""
        return rig.replace(panorama_rotation=np.asarray(self.panorama_rotation, np.float32))

    def scaled_rig(self, rig):
        """``rig`` at the exported image size (scaled by the model's image scale if needed)."""
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

    def feed(self, rig, images, masks=None, candidates=None, batch: int | None = 1, log=None):
        """(input feed for one sample repeated to ``batch``, candidates used).

        ``images`` (N, h, w, 3) uint8 or float RGB in [0, 1] of the rig's aspect ratio, resized
        to the exported size when needed (:func:`gijax.data.images.fit_images`, the size policy
        of every method; ``log`` receives its note); ``masks`` (N, h, w) or None for the rig's
        own masks; ``candidates`` (D,) metres, only selectable for rig-as-input files (default:
        the exported list).
        """
        from gijax.data.images import fit_images

        images = np.asarray(images)
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"images must have shape (num_cameras, height, width, 3); found "
                             f"{images.shape}")
        if images.shape[0] != self.num_cameras or rig.num_cameras != self.num_cameras:
            raise ValueError(f"{self.path} was exported for {self.num_cameras} cameras; found "
                             f"{images.shape[0]} images and a rig with {rig.num_cameras}")
        run_rig = self.scaled_rig(rig)
        h, w = self.image_hw
        if masks is not None:
            masks = np.asarray(masks, np.float32)
            if masks.shape != images.shape[:3]:
                raise ValueError(f"masks must have shape {images.shape[:3]} to match the "
                                 f"images; found {masks.shape}")
        _, images, masks = fit_images(rig, images, masks, (h, w), log)
        if masks is None:
            masks = np.stack([np.ones((h, w), np.float32) if m is None else np.asarray(m)
                              for m in run_rig.masks])
        masks = np.asarray(masks, np.float32)
        if masks.shape != images.shape[:3]:
            raise ValueError(f"masks must have shape {images.shape[:3]}; found {masks.shape}")
        if np.issubdtype(images.dtype, np.integer):
            images = images.astype(np.float32) / 255.0
        feed = {IMAGES: images.astype(np.float32)[None], MASKS: masks[None]}
        if batch not in (None, 1):
            feed = {k: np.repeat(v, batch, axis=0) for k, v in feed.items()}
        cand = self.candidates
        if candidates is not None:
            cand = np.asarray(candidates, np.float64)
            if cand.shape != self.candidates.shape:
                raise ValueError(f"{self.path} needs {len(self.candidates)} candidates; found "
                                 f"shape {cand.shape}")
            if not self.rig_as_input and not np.allclose(cand, self.candidates, rtol=1e-6):
                raise ValueError(f"{self.path} has its candidates baked in "
                                 f"({np.round(self.candidates, 4).tolist()} m); export with "
                                 f"--rig-as-input to choose candidates at run time")
        if self.rig_as_input:
            layout = json.loads(self.meta["intrinsics_layout"])
            if list(intrinsics_layout(run_rig)) != layout:
                raise ValueError(f"{self.path} takes {self.meta['camera_model']!r} intrinsics "
                                 f"{layout}; the rig's cameras have "
                                 f"{list(intrinsics_layout(run_rig))}")
            feed.update(rig_feed(run_rig, cand))
        return feed, cand


class OnnxPredictor:
    """An exported model: ``predict(rig, images, masks=None, candidates=None) -> Prediction``.

    Args:
      path: the ``.onnx`` file.
      providers: onnxruntime execution providers; default CUDA where available, else CPU.
      threads: intra-op threads (default: onnxruntime's choice).
      memory: ``'default'``, ``'lean'`` or ``'low'`` (:mod:`gijax.export.ort_session`: less
        resident memory for more time).
    """

    def __init__(self, path: str | os.PathLike, providers=None, threads: int | None = None,
                 memory: str = "default"):
        self.info = ExportInfo(path)
        self.path = self.info.path
        self.session = make_session(self.path, providers, threads, memory)
        first = self.session.get_inputs()[0]
        self.batch = first.shape[0] if isinstance(first.shape[0], int) else None

    @property
    def providers(self) -> list[str]:
        return self.session.get_providers()

    @property
    def candidates(self) -> np.ndarray:
        return self.info.candidates

    def predict(self, rig, images, masks=None, candidates=None, log=None) -> Prediction:
        """One sample (see :meth:`ExportInfo.feed` for the arguments).

        Returns a :class:`Prediction` of numpy ``inv_distance`` (H, W) 1/m, ``distance``
        (H, W) m, ``entropy`` (H, W) nats, ``valid`` (H, W) bool, ``candidates`` (D,) metres
        and ``panorama`` (the exported :class:`~gijax.geometry.panorama.Panorama`, oriented by
        ``self.info.panorama_rotation``).
        """
        feed, cand = self.info.feed(rig, images, masks, candidates, self.batch, log)
        got = self.run_batch(feed)
        out = {k: np.asarray(got[k][0]) for k in OUTPUTS}
        out["valid"] = out["valid"] > 0.5
        return Prediction(**out, candidates=cand, panorama=self.info.panorama)

    def run_batch(self, feed: dict) -> dict:
        """Raw session call: ``feed`` maps input names to arrays; returns all outputs."""
        names = [o.name for o in self.session.get_outputs()]
        return dict(zip(names, self.session.run(names, feed)))


__all__ = ["OnnxPredictor", "ExportInfo", "make_session", "rig_feed", "default_providers",
           "available_providers", "MEMORY_PROFILES", "RIG_INPUTS"]
