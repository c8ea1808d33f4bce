"""Random access to the samples of one partition of a release-layout dataset.

What the reader returns, in gijax's conventions (docs/architecture.md):

* ``images``: each camera's raw fisheye, uint8 RGB (converted from BGR). Where masks.json has
  ``masks_augmented`` for a camera, pixels outside that mask are 0, as the release does.
* ``masks``: masks.json's ``masks``, uint8 1 = valid, at each camera's raw resolution.
* ``pano_distance``: the ground truth on gijax's panorama. The release resamples the rig's raw
  distance image (camera model = the manifest's ``rig`` sampler, frame ``rif``) into an
  equirectangular image in frame ``rifs`` (latitude -90..0 deg with the pole on ``rifs``' -y
  axis, longitude atan2(x, z)), blending nearest and bilinear samples at depth edges, with
  1e6 m where the rig camera does not see. This reader performs the same resampling
  (:class:`gijax.data.release.labels.LabelResampler`) and stores it in gijax's panorama
  convention, whose frame G is right-handed with ``z_G = -y_rifs``, ``x_G = z_rifs``, ``y_G = -x_rifs``: that panorama is the
  release's one, pixel for pixel (both in the common equirectangular layout).
* ``rig``: a :class:`gijax.geometry.Rig` in frame G with its origin at the ``rif`` origin (the
  centre of the distance labels); camera k's pose is the pose of its ``image_frame``.
"""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np

from gijax.data import format as fmt
from gijax.data.reader import VERIFY_MODES, RowReader, Skipped
from gijax.data.release.cameras import ReleaseCameraModel, gijax_camera
from gijax.data.release.frame_graph import FrameGraph
from gijax.data.release.images import read_release_distance, read_release_mask, read_release_rgb
from gijax.data.release.labels import LabelResampler
from gijax.data.release.file_lists import partition_rows
from gijax.data.release.layout import (DIST_SUFFIX, FRAME_GRAPH, LABEL_PANO, MANIFEST, MASKS,
                                       METADATA, R_G_FROM_E, RGB_SUFFIX, RIG_KEY,
                                       RIG_LABEL_FRAME, RIG_RAW_FRAME)
from gijax.geometry.occluder import FAR
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import make_rig


class ReleaseDatasetReader(RowReader):
    """Random access to the samples of one partition of a release-layout dataset.

    Args:
      root: the folder holding manifest.json, metadata.json, frame_graph.json, masks.json and
        data_partitions.json.
      split: the data_partitions.json key (the release trains on ``train`` and validates on
        ``validate``).
      masks_file: masks.json's path relative to ``root`` (the release's ``mask_path``).
      rgb_suffix, dist_suffix: CSV column suffixes (columns ``cam<k><rgb_suffix>`` and
        ``rig<dist_suffix>``, optionally ``cam<k><dist_suffix>``).
      label_frame: the frame of the ground-truth panorama (the release's
        ``map_camera_frame["rig"]``).
      pano: the label panorama (the release's 160 x 640, latitude -90..0 deg).
      verify: ``"none"``, ``"exists"`` (every listed file exists; the default) or ``"full"``
        (every file decodes with the right size).
      skip_bad: drop rows that fail verification (listed in ``skipped``) instead of raising.

    ``reader[i]`` is a dict like :class:`gijax.data.DatasetReader`'s: ``images`` uint8
    (N, h, w, 3) RGB, ``masks`` uint8 (N, h, w), ``pano_distance`` float32 (H, W) metres,
    ``distances`` float32 (N, h, w) only when the CSV has ``cam<k><dist_suffix>`` columns,
    ``rig``, ``index``, ``trajectory``, ``frame`` (row in its CSV), ``seed`` (None).
    """

    def __init__(self, root, split: str = "train", masks_file: str = MASKS,
                 rgb_suffix: str = RGB_SUFFIX, dist_suffix: str = DIST_SUFFIX,
                 label_frame: str = RIG_LABEL_FRAME, pano: Panorama = LABEL_PANO,
                 verify: str = "exists", skip_bad: bool = False):
        if verify not in VERIFY_MODES:
            raise ValueError(f"verify must be one of {VERIFY_MODES}; found {verify!r}")
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"dataset folder {self.root} does not exist")
        self.split, self.pano = split, pano
        self.rgb_suffix, self.dist_suffix = rgb_suffix, dist_suffix
        self.distance_range = fmt.DEFAULT_DISTANCE_RANGE
        self.sky_distance = FAR
        self.skip_bad = skip_bad
        self.skipped: list[Skipped] = []

        manifest_path = self.root / MANIFEST
        manifest = fmt.load_json(manifest_path, "manifest")
        models = fmt.document_field(manifest, "camera_models", manifest_path, dict)
        samplers = fmt.document_field(manifest, "samplers", manifest_path, list)
        model_of: dict[str, str] = {}
        for k, s in enumerate(samplers):
            where = f"{manifest_path} samplers[{k}]"
            if not isinstance(s, dict):
                raise ValueError(f"{where}: must be an object; found {type(s).__name__}")
            if fmt.document_field(s, "mvs_main_cam_model_for_cam", where, bool):
                key = fmt.document_field(s, "mvs_cam_key", where, str)
                sampler = fmt.document_field(s, "sampler", where, dict)
                model_key = fmt.document_field(sampler, "cam_model_key", f"{where} sampler", str)
                if model_key not in models:
                    raise ValueError(f"{where}: sampler cam_model_key {model_key!r} is not in "
                                     f"camera_models; found {sorted(models)}")
                model_of[key] = model_key

        meta_path = self.root / METADATA
        meta = fmt.load_json(meta_path, "metadata")
        cams = fmt.document_field(meta, "cams", meta_path, list)
        if not cams:
            raise ValueError(f"{meta_path}: field 'cams' is empty")
        self.names = [f"cam{k}" for k in range(len(cams))]
        graph = FrameGraph(self.root / FRAME_GRAPH)

        for key in self.names + [RIG_KEY]:
            if key not in model_of:
                raise ValueError(f"{manifest_path}: no sampler with mvs_main_cam_model_for_cam "
                                 f"true and mvs_cam_key {key!r} (the camera model of {key!r}); "
                                 f"found keys {sorted(model_of)}")
        rig_spec = models[model_of[RIG_KEY]]
        rig_model = ReleaseCameraModel(rig_spec, f"{manifest_path} camera_models"
                                                 f"[{model_of[RIG_KEY]!r}]")
        R_rif_label = graph.query(RIG_RAW_FRAME, label_frame, "rig label frame")[:3, :3]
        self._label = LabelResampler(rig_model, R_rif_label, pano)
        self.rig_hw = (rig_model.height, rig_model.width)

        # Frame G: the label frame's axes re-labelled for gijax's panorama, origin at rif.
        R_g_rif = R_G_FROM_E @ R_rif_label.T
        cameras, rots, trans = [], [], []
        for k, name in enumerate(self.names):
            where = f"{meta_path} cams[{k}]"
            if not isinstance(cams[k], dict):
                raise ValueError(f"{where}: must be an object; found {type(cams[k]).__name__}")
            frame = fmt.document_field(cams[k], "image_frame", where, str)
            cameras.append(gijax_camera(models[model_of[name]], f"{manifest_path} camera_models"
                                                                 f"[{model_of[name]!r}]"))
            T = graph.query(RIG_RAW_FRAME, frame, f"image_frame of {name}")
            rots.append(R_g_rif @ T[:3, :3])
            trans.append(R_g_rif @ T[:3, 3])
        self.hw = [(c.height, c.width) for c in cameras]

        self.masks, self._aug_masks = self._read_masks(masks_file)
        self.rig = make_rig(cameras, np.stack(rots), np.stack(trans), np.zeros(3),
                            masks=[jnp.asarray(m, jnp.float32) for m in self.masks],
                            names=self.names)
        self._rows = partition_rows(self.root, split, self.names, rgb_suffix, dist_suffix)
        if verify != "none":
            kept = []
            for entry in self._rows:
                try:
                    self._check(entry, full=verify == "full")
                except (FileNotFoundError, ValueError) as exc:
                    if not skip_bad:
                        raise
                    self.skipped.append(Skipped(str(entry["csv"]), entry["line"], str(exc)))
                    continue
                kept.append(entry)
            self._rows = kept

    # -- documents

    def _read_masks(self, masks_file: str):
        path = self.root / masks_file
        doc = fmt.load_json(path, "masks file")
        found: dict[str, dict[str, Path]] = {}
        for field in ("masks", "masks_augmented"):
            if field == "masks_augmented" and field not in doc:
                continue
            entries = fmt.document_field(doc, field, path, list)
            found[field] = {}
            for k, e in enumerate(entries):
                where = f"{path} {field}[{k}]"
                cam = fmt.document_field(e, "raw_camera", where, str)
                found[field][cam] = self.root / fmt.document_field(e, "mask", where, str)
        missing = [n for n in self.names if n not in found["masks"]]
        if missing:
            raise ValueError(f"{path}: field 'masks' has no entry for camera(s) {missing} "
                             f"(raw_camera); found {sorted(found['masks'])}")
        masks = [read_release_mask(found["masks"][n], hw, f"mask of {n} in {path}")
                 for n, hw in zip(self.names, self.hw)]
        aug = {}
        for n, p in found.get("masks_augmented", {}).items():
            if n in self.names:
                aug[n] = read_release_mask(p, self.hw[self.names.index(n)],
                                           f"augmented mask of {n} in {path}")
        return masks, aug

    # -- samples

    def __len__(self) -> int:
        return len(self._rows)

    def report(self) -> str:
        lines = [f"{self.root} ({self.split}): {len(self)} samples, {len(self.skipped)} bad "
                 f"row(s) skipped"]
        return "\n".join(lines + [f"  {s.file_list} line {s.line}: {s.reason}"
                                  for s in self.skipped])

    def location(self, index: int) -> str:
        e = self._rows[index]
        return f"{e['csv']} line {e['line']}"

    def _check(self, entry, full: bool) -> None:
        if full:
            self._load(entry)
            return
        where = f"{entry['csv']} line {entry['line']}"
        for p in entry["rgb"] + [entry["label"]] + (entry["dist"] or []):
            if not p.is_file():
                raise FileNotFoundError(f"missing file {p} ({where})")

    def _load(self, entry) -> dict:
        where = f"{entry['csv']} line {entry['line']}"
        images = []
        for name, p, hw in zip(self.names, entry["rgb"], self.hw):
            img = read_release_rgb(p, hw, where)
            if name in self._aug_masks:
                img = img * self._aug_masks[name][..., None]
            images.append(img)
        raw = read_release_distance(entry["label"], self.rig_hw, where)
        same = len(set(self.hw)) == 1
        stack = np.stack if same else list
        sample = {"images": stack(images), "masks": stack(self.masks),
                  "pano_distance": self._label(raw), "trajectory": entry["trajectory"],
                  "frame": entry["frame"], "seed": None}
        if entry["dist"] is not None:
            sample["distances"] = stack([read_release_distance(p, hw, where)
                                         for p, hw in zip(entry["dist"], self.hw)])
        return sample
