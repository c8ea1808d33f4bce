"""Read a dataset tree laid out as the paper's released training code expects.

The release's dataset class (``MultiViewCameraModelDataset``) and its manifest parser open a
folder holding::

    ROOT/
      manifest.json          "camera_models": {key: {"type": ..., model parameters}},
                             "samplers": [{"mvs_main_cam_model_for_cam": bool,
                                           "mvs_cam_key": "cam0" | ... | "rig",
                                           "sampler": {"cam_model_key": key, ...}}, ...]
      metadata.json          "cams": [{"image_frame": "cif0", ...}, ...]  (camera k = "cam<k>")
      frame_graph.json       "frames", "typical_poses", "transforms" (poses T_f0_f1)
      masks.json             "masks": [{"raw_camera": "cam0", "mask": "valid_mask_0.png"}, ...],
                             optional "masks_augmented" (same shape)
      data_partitions.json   {split: {environment: [trajectory folder | CSV path, ...]}}
      ENV/TRAJ/meta.json     {"selected_file_list": "<name>.csv"}
      ENV/TRAJ/<name>.csv    columns cam<k>_rgb_fisheye, rig_dist_fisheye (paths relative to
                             ENV/TRAJ; a CSV named directly in data_partitions.json holds paths
                             relative to ROOT)

Encodings (the release's ``mvs_utils.image_io``): colour images are read with OpenCV unchanged,
so their channels are BGR; distances are float32 metres whose four little-endian bytes are the
four channels of an 8-bit PNG (as OpenCV orders them); a mask pixel is valid where its
greyscale value is exactly 255.

What the reader returns, in gijax's conventions (docs/architecture.md):

* ``images``: each camera's raw fisheye, uint8 RGB (converted from BGR). Where masks.json has
  ``masks_augmented`` for a camera, pixels outside that mask are 0, as the release does.
* ``masks``: masks.json's ``masks``, uint8 1 = valid, at each camera's raw resolution.
* ``pano_distance``: the ground truth on gijax's panorama. The release resamples the rig's raw
  distance image (camera model = the manifest's ``rig`` sampler, frame ``rif``) into an
  equirectangular image in frame ``rifs`` (latitude -90..0 deg with the pole on ``rifs``' -y
  axis, longitude atan2(x, z)), blending nearest and bilinear samples at depth edges, with
  1e6 m where the rig camera does not see. This reader performs the same resampling (see
  :func:`resample_rig_distance`) and stores it in gijax's panorama convention, whose frame G is
  right-handed with ``z_G = -y_rifs``, ``x_G = z_rifs``, ``y_G = -x_rifs``: that panorama is the
  release's one, pixel for pixel (both in the common equirectangular layout).
* ``rig``: a :class:`gijax.geometry.Rig` in frame G with its origin at the ``rif`` origin (the
  centre of the distance labels); camera k's pose is the pose of its ``image_frame``.

The release measures pixel coordinates from the image corner (pixel centres at i + 0.5);
gijax from the first pixel's centre, so principal points lose 0.5 px on conversion.
"""

from __future__ import annotations

import collections
import math
from pathlib import Path

import cv2
import jax.numpy as jnp
import numpy as np

from gijax.data import format as fmt
from gijax.data import pngio
from gijax.io.png import is_png, read_png
from gijax.data.reader import VERIFY_MODES, RowReader, Skipped
from gijax.geometry import cameras as cam_lib
from gijax.geometry.occluder import FAR
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import make_rig
from gijax.io.parsing import Where, checked_camera, floats, resolution

MANIFEST = "manifest.json"
METADATA = "metadata.json"
FRAME_GRAPH = "frame_graph.json"
PARTITIONS = "data_partitions.json"
MASKS = "masks.json"
TRAJ_META = "meta.json"
# The release's defaults (MultiViewCameraModelDataset and its data module).
RGB_SUFFIX = "_rgb_fisheye"
DIST_SUFFIX = "_dist_fisheye"
RIG_KEY = "rig"
RIG_RAW_FRAME = "rif"       # hard-coded in the release (find_rig_raw_frame)
RIG_LABEL_FRAME = "rifs"    # map_camera_frame["rig"] of the release's configurations
LABEL_PANO = Panorama.hemisphere(160, 640)
BLEND_THRESHOLD_SCALE = 0.01  # BlendBy2ndOrderGradTorch threshold_scaling_factor in the release
BLEND_THRESHOLD_MAX = 10.0
# Tolerance on |R^T R - I| of a frame graph's rotation_matrix.
RELEASE_ROTATION_TOL = 1e-3
# Rotation taking release-panorama (rifs) coordinates to gijax panorama coordinates.
R_G_FROM_E = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

SUPPORTED_MODELS = ("DoubleSphere", "LinearSphere")


# ---------------------------------------------------------------------------- detection

def detect_layout(root) -> str:
    """``"gijax"`` or ``"release"`` from the files in ``root``; a clear error when neither."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"dataset folder {root} does not exist")
    manifest = root / MANIFEST
    if not manifest.is_file():
        raise FileNotFoundError(
            f"{root} is not a dataset: missing {MANIFEST} (a gijax dataset has manifest.json "
            f"with format {fmt.FORMAT_NAME!r}; the release layout has manifest.json with "
            f"'camera_models' beside {PARTITIONS})")
    doc = fmt.load_json(manifest, "manifest")
    if doc.get("format") == fmt.FORMAT_NAME or "trajectories" in doc:
        return "gijax"
    if "camera_models" in doc or (root / PARTITIONS).is_file():
        return "release"
    raise ValueError(f"{manifest}: neither a gijax manifest (field 'format' = "
                     f"{fmt.FORMAT_NAME!r}) nor the release's (field 'camera_models'); found "
                     f"fields {sorted(doc)}")


def open_reader(root, split: str = "train", allow_partial: bool = False, **kw):
    """A reader for either layout: :class:`gijax.data.DatasetReader` for gijax's own,
    :class:`ReleaseDatasetReader` (partition ``split``) for the release's.

    ``allow_partial`` concerns gijax datasets only (the release layout records no requested
    sample count); other keywords go to the reader of the detected layout.
    """
    if detect_layout(root) == "release":
        return ReleaseDatasetReader(root, split=split, **kw)
    from gijax.data.reader import DatasetReader

    if allow_partial:
        kw["allow_partial"] = True
    return DatasetReader(root, **kw)


# ---------------------------------------------------------------------------- frame graph

def _orientation(doc, where) -> np.ndarray:
    """A rotation matrix. The release uses a matrix as it is; one that is far from a rotation
    (beyond :data:`RELEASE_ROTATION_TOL`, looser than a calibration file's since these files
    print few digits) is refused, since every pose chained through it would be skewed."""
    kind = fmt.require(doc, "type", where, str)
    data = fmt.require(doc, "data", where, (list, dict))
    if kind == "rotation_matrix":
        m = floats(data, 9, "data", Where(where), "9 numbers (row-major 3x3)").reshape(3, 3)
        err = float(np.abs(m.T @ m - np.eye(3)).max())
        if err > RELEASE_ROTATION_TOL or np.linalg.det(m) <= 0:
            raise ValueError(f"{where}: rotation_matrix data must be a proper rotation "
                             f"(|R^T R - I| = {err:.3g}, det = {np.linalg.det(m):.3g}); found "
                             f"{m.tolist()}")
        return m
    if kind == "quaternion":
        if not isinstance(data, dict):
            raise ValueError(f"{where}: quaternion data must be an object with x, y, z, w")
        q = np.array([_num(data, k, where) for k in "wxyz"], np.float64)
        n = np.linalg.norm(q)
        if not n > 1e-12 or not math.isfinite(n):
            raise ValueError(f"{where}: quaternion has norm {n:.3g}; expected a rotation")
        w, x, y, z = q / n  # the release's pyquaternion normalises before building the matrix
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    raise ValueError(f"{where}: orientation type must be 'rotation_matrix' or 'quaternion'; "
                     f"found {kind!r}")


def _pose(doc, where) -> np.ndarray:
    t = floats(fmt.require(doc, "position", where, list), 3, "position", Where(where),
               "3 numbers in metres")
    T = np.eye(4)
    T[:3, :3] = _orientation(fmt.require(doc, "orientation", where, dict), f"{where} orientation")
    T[:3, 3] = t
    return T


class FrameGraph:
    """frame_graph.json: 4x4 transforms ``T_f0_f1`` (``p_f0 = T_f0_f1 @ p_f1``), metres."""

    def __init__(self, path: Path):
        self.path = path
        doc = fmt.load_json(path, "frame graph")
        frames = fmt.require(doc, "frames", path, list)
        typical = fmt.require(doc, "typical_poses", path, dict)
        transforms = fmt.require(doc, "transforms", path, list)
        self.edges: dict[str, dict[str, np.ndarray]] = collections.defaultdict(dict)
        for k, f in enumerate(frames):
            name = fmt.require(f, "name", f"{path} frames[{k}]", str)
            self.edges.setdefault(name, {})
        poses = {key: _pose(v, f"{path} typical_poses[{key!r}]") for key, v in typical.items()}
        for k, tr in enumerate(transforms):
            where = f"{path} transforms[{k}]"
            f0 = fmt.require(tr, "f0", where, str)
            f1 = fmt.require(tr, "f1", where, str)
            pose = fmt.require(tr, "pose", where, dict)
            kind = fmt.require(pose, "type", f"{where} pose", str)
            if kind == "create":
                T = _pose(pose, f"{where} pose")
            elif kind == "reference":
                key = fmt.require(pose, "key", f"{where} pose", str)
                if key not in poses:
                    raise ValueError(f"{where}: pose references typical_poses[{key!r}], which "
                                     f"does not exist; found {sorted(poses)}")
                T = poses[key]
            else:
                raise ValueError(f"{where}: pose type must be 'create' or 'reference'; found "
                                 f"{kind!r}")
            self.edges[f0][f1] = T
            self.edges[f1][f0] = np.linalg.inv(T)

    def query(self, f0: str, f1: str, why: str = "") -> np.ndarray:
        """``T_f0_f1`` along the shortest chain of transforms (as the release's FrameGraph)."""
        for f in (f0, f1):
            if f not in self.edges:
                suffix = f" ({why})" if why else ""
                raise ValueError(f"{self.path}: no frame {f!r}{suffix}; frames are "
                                 f"{sorted(self.edges)}")
        prev = {f0: None}
        queue = collections.deque([f0])
        while queue and f1 not in prev:
            a = queue.popleft()
            for b in self.edges[a]:
                if b not in prev:
                    prev[b] = a
                    queue.append(b)
        if f1 not in prev:
            raise ValueError(f"{self.path}: no chain of transforms links frames {f0!r} and {f1!r}")
        chain = [f1]
        while prev[chain[-1]] is not None:
            chain.append(prev[chain[-1]])
        chain.reverse()
        T = np.eye(4)
        for a, b in zip(chain[:-1], chain[1:]):
            T = T @ self.edges[a][b]
        return T


# ---------------------------------------------------------------------------- camera models

def _shape(spec, where) -> tuple[int, int]:
    """shape_struct (H, W): positive and within the image-size bounds."""
    ss = fmt.require(spec, "shape_struct", where, dict)
    h = fmt.require(ss, "H", f"{where} shape_struct", int)
    w = fmt.require(ss, "W", f"{where} shape_struct", int)
    resolution([w, h], Where(f"{where} shape_struct"))
    return int(h), int(w)


def _num(spec, key, where) -> float:
    """A finite number (JSON's NaN and Infinity are refused)."""
    value = fmt.require(spec, key, where, (int, float))
    return float(floats(value, 1, key, Where(where), "one finite number")[0])


def _fov(spec, where) -> float:
    fov = _num(spec, "fov_degree", where)
    if not 0.0 < fov <= 360.0:
        raise ValueError(f"{where}: field 'fov_degree' must lie in (0, 360] degrees; found {fov}")
    return fov


class ReleaseCameraModel:
    """One entry of the manifest's ``camera_models``, projecting as the release's
    ``mvs_utils.camera_models`` does (release pixel coordinates: centres at i + 0.5).

    Only what the label resampling needs: :meth:`project`. Types: DoubleSphere, LinearSphere,
    Equirectangular. ``padding`` is how the release's grid_sample treats samples outside the
    image: zeros for fisheye models, the border for Equirectangular.
    """

    def __init__(self, spec: dict, where: str):
        self.where = where
        self.type = fmt.require(spec, "type", where, str)
        self.height, self.width = _shape(spec, where)
        self.padding = "zeros"
        if self.type == "DoubleSphere":
            for k in ("fx", "fy", "cx", "cy", "xi", "alpha"):
                setattr(self, k, _num(spec, k, where))
            self.fov_degree = _fov(spec, where)
            a, xi = self.alpha, self.xi
            if not 0.0 <= a <= 1.0 or self.fx <= 0 or self.fy <= 0:
                raise ValueError(f"{where}: DoubleSphere needs alpha in [0, 1] and positive fx, "
                                 f"fy; found alpha={a}, fx={self.fx}, fy={self.fy}")
            w1 = a / (1 - a) if a <= 0.5 else (1 - a) / a
            radicand = 2 * w1 * xi + xi * xi + 1
            if not radicand > 0:
                raise ValueError(f"{where}: DoubleSphere xi={xi} with alpha={a} has no valid "
                                 f"projection region")
            self.w2 = (w1 + xi) / math.sqrt(radicand)
        elif self.type == "LinearSphere":
            self.fov_degree = _fov(spec, where)
            if self.height != self.width:
                raise ValueError(f"{where}: a LinearSphere image must be square; found "
                                 f"shape_struct H={self.height}, W={self.width}")
        elif self.type == "Equirectangular":
            self.padding = "border"
            at = Where(where)
            lon = floats(spec.get("longitude_span", [-math.pi, math.pi]), 2, "longitude_span",
                         at, "2 numbers (radians)")
            lat = floats(spec.get("latitude_span", [-math.pi / 2, math.pi / 2]), 2,
                         "latitude_span", at, "2 numbers (radians)")
            if not (lon[1] > lon[0] and lat[1] > lat[0]):
                raise ValueError(f"{where}: longitude_span and latitude_span must be increasing; "
                                 f"found {lon.tolist()}, {lat.tolist()}")
            self.lon0, self.lat0, self.lat1 = float(lon[0]), float(lat[0]), float(lat[1])
            self.lon_span = float(lon[1]) - float(lon[0])
            if spec.get("open_span", False):
                self.lon_span *= (self.width - 1) / self.width
        else:
            raise ValueError(f"{where}: camera model type {self.type!r} is not supported for the "
                             f"rig's distance labels; supported: DoubleSphere, LinearSphere, "
                             f"Equirectangular")

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points (..., 3) -> release pixel coordinates u, v and validity, as the release."""
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.type == "DoubleSphere":
                d1 = np.sqrt(x * x + y * y + z * z)
                d2 = np.sqrt(x * x + y * y + (self.xi * d1 + z) ** 2)
                t = self.alpha * d2 + (1 - self.alpha) * (self.xi * d1 + z)
                u, v = self.fx * x / t + self.cx, self.fy * y / t + self.cy
                angle = np.arctan2(np.sqrt(x * x + y * y), z)
                valid = (z > -self.w2 * d1) & (angle <= math.radians(self.fov_degree) / 2)
            elif self.type == "LinearSphere":
                ph = np.arccos(z / np.sqrt(x * x + y * y + z * z))
                th = np.arctan2(y, x)
                r = ph * self.width / math.radians(self.fov_degree)
                u, v = r * np.cos(th) + self.width / 2, r * np.sin(th) + self.height / 2
                # The release's LinearSphere checks only that the pixel is inside the image.
                valid = (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
            else:
                lat = np.arctan2(y, np.hypot(z, x))
                lon = np.arctan2(x, z)
                u = (lon - self.lon0) / self.lon_span * self.width
                v = (lat - self.lat0) / (self.lat1 - self.lat0) * self.height
                valid = np.ones(u.shape, bool)
        valid &= np.isfinite(u) & np.isfinite(v)
        return np.where(valid, u, 0.0), np.where(valid, v, 0.0), valid


def gijax_camera(spec: dict, where: str):
    """The gijax camera model of a manifest ``camera_models`` entry (input cameras).

    DoubleSphere -> ``ds`` with the same fx, fy, xi, alpha and fov, cx and cy minus 0.5 (pixel
    centre convention); LinearSphere (r = theta * W / fov) -> ``equidistant`` with
    fx = fy = W / fov_rad and the principal point at the image centre. Other release types
    (Equirectangular, Pinhole, Ocam) have no gijax camera model and are refused.
    """
    kind = fmt.require(spec, "type", where, str)
    h, w = _shape(spec, where)
    if kind == "DoubleSphere":
        p = {k: _num(spec, k, where) for k in ("fx", "fy", "cx", "cy", "xi", "alpha")}
        p["cx"] -= 0.5
        p["cy"] -= 0.5
        return checked_camera("ds", p, (w, h), _fov(spec, where), Where(where))
    if kind == "LinearSphere":
        if h != w:
            raise ValueError(f"{where}: a LinearSphere image must be square; found "
                             f"shape_struct H={h}, W={w}")
        fov_deg = _fov(spec, where)
        f = w / math.radians(fov_deg)
        c = w / 2 - 0.5
        return checked_camera("equidistant", {"fx": f, "fy": f, "cx": c, "cy": c}, (w, h),
                              fov_deg, Where(where))
    raise ValueError(f"{where}: camera model type {kind!r} has no gijax equivalent for an input "
                     f"camera; supported: {', '.join(SUPPORTED_MODELS)} (gijax models: "
                     f"{', '.join(sorted(cam_lib.CAMERA_MODELS))})")


# ---------------------------------------------------------------------------- label resampling

def _correlate(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """2-D cross-correlation with replicated borders (kornia's spatial_gradient padding)."""
    r = kernel.shape[0] // 2
    pad = np.pad(img, r, mode="edge")
    h, w = img.shape
    out = np.zeros((h, w), np.float64)
    for i in range(kernel.shape[0]):
        for j in range(kernel.shape[1]):
            if kernel[i, j] != 0.0:
                out += kernel[i, j] * pad[i:i + h, j:j + w]
    return out


_GXX = np.array([[-1, 0, 2, 0, -1], [-4, 0, 8, 0, -4], [-6, 0, 12, 0, -6],
                 [-4, 0, 8, 0, -4], [-1, 0, 2, 0, -1]], np.float64)
_GXY = np.array([[-1, -2, 0, 2, 1], [-2, -4, 0, 4, 2], [0, 0, 0, 0, 0],
                 [2, 4, 0, -4, -2], [1, 2, 0, -2, -1]], np.float64)
_SOBEL2 = [k / np.abs(k).sum() for k in (_GXX, _GXY, _GXX.T)]


def blend_factor(distance: np.ndarray, scale: float = BLEND_THRESHOLD_SCALE,
                 max_threshold: float = BLEND_THRESHOLD_MAX) -> np.ndarray:
    """1 where the release takes the nearest sample instead of the bilinear one.

    The release's BlendBy2ndOrderGradTorch: the norm of the three L1-normalised 5x5 Sobel
    second derivatives (xx, xy, yy) must exceed ``clip(d * scale, scale, max_threshold)``,
    then a 3x3 erosion that ignores pixels outside the image.
    """
    d = np.asarray(distance, np.float64)
    s = np.sqrt(sum(_correlate(d, k) ** 2 for k in _SOBEL2))
    m = (s > np.clip(d * scale, scale, max_threshold)).astype(np.float64)
    pad = np.pad(m, 1, mode="constant", constant_values=np.inf)
    h, w = m.shape
    return np.min([pad[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)


def _bilinear(img, u, v, border: bool):
    """grid_sample bilinear, align_corners=False, on release pixel coordinates."""
    h, w = img.shape
    x, y = u - 0.5, v - 0.5
    if border:
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    out = np.zeros(u.shape, np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            val = img[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)]
            out += np.where(inside, wx * wy * val, 0.0)
    return out


def _nearest_index(u, v, h, w, border: bool):
    """grid_sample nearest with align_corners=True (as the release's samplers use it)."""
    x = (u / w) * (w - 1)
    y = (v / h) * (h - 1)
    if border:
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    xi, yi = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    return np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1), inside


class LabelResampler:
    """The release's rig-distance -> panorama resampling, returned in gijax's panorama.

    ``R_raw_label`` rotates label-frame (``rifs``) coordinates into the rig camera's frame
    (``rif``); translation is ignored, as in the release's rotation-only sampler.
    """

    def __init__(self, model: ReleaseCameraModel, R_raw_label: np.ndarray, pano: Panorama):
        self.model, self.pano = model, pano
        h, w = pano.shape
        col = (np.arange(w) + 0.5) / w
        row = (np.arange(h) + 0.5) / h
        lon, lat = np.meshgrid(-math.pi + 2 * math.pi * col,
                               pano.lat_min + (pano.lat_max - pano.lat_min) * row)
        ray_e = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], -1)
        u, v, self.valid = model.project(ray_e @ np.asarray(R_raw_label, np.float64).T)
        self.u, self.v = u, v
        border = model.padding == "border"
        self.near = _nearest_index(u, v, model.height, model.width, border)

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        m = self.model
        border = m.padding == "border"
        raw = np.asarray(raw, np.float64)
        linear = _bilinear(raw, self.u, self.v, border)
        yi, xi, inside = self.near
        nearest = np.where(inside, raw[yi, xi], 0.0)
        f = np.where(inside, blend_factor(raw)[yi, xi], 0.0)
        out = f * nearest + (1 - f) * linear
        out = np.where(self.valid, out, FAR)
        # Both panoramas grow in longitude to the right: column c is column c.
        return np.ascontiguousarray(out).astype(np.float32)


def resample_rig_distance(raw: np.ndarray, model: ReleaseCameraModel, R_raw_label: np.ndarray,
                          pano: Panorama = LABEL_PANO) -> np.ndarray:
    """One rig distance image (model's shape, metres) -> gijax panorama label (H, W) metres."""
    return LabelResampler(model, R_raw_label, pano)(raw)


# ---------------------------------------------------------------------------- image files

def _read_any(path: Path, where: str, flags=cv2.IMREAD_UNCHANGED) -> np.ndarray:
    suffix = f" ({where})" if where else ""
    if not path.is_file():
        raise FileNotFoundError(f"missing file {path}{suffix}")
    if is_png(path):
        image = read_png(path, where)  # detects truncated PNGs
        if flags == cv2.IMREAD_GRAYSCALE and image.ndim == 3:
            code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            image = cv2.cvtColor(image, code)
        return image
    image = cv2.imread(str(path), flags)
    if image is None:
        raise ValueError(f"{path}: OpenCV cannot decode this image{suffix}")
    return image


def _check_hw(image, hw, path, what, where):
    if tuple(image.shape[:2]) != tuple(hw):
        raise ValueError(f"{path}: {what} must be {hw[1]}x{hw[0]} (WxH, from {MANIFEST}); found "
                         f"{image.shape[1]}x{image.shape[0]}" + (f" ({where})" if where else ""))


def read_release_rgb(path: Path, hw, where: str = "") -> np.ndarray:
    """A colour image as the release reads it (BGR), returned uint8 (h, w, 3) RGB."""
    image = _read_any(path, where)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{path}: colour image must be 8-bit with 3 channels; found "
                         f"{image.dtype} with shape {image.shape}"
                         + (f" ({where})" if where else ""))
    _check_hw(image, hw, path, "colour image", where)
    return np.ascontiguousarray(image[..., ::-1])


def read_release_distance(path: Path, hw, where: str = "") -> np.ndarray:
    """A float32-in-4-channel-PNG distance image, metres (h, w)."""
    image = _read_any(path, where)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 4:
        raise ValueError(f"{path}: distance image must be an 8-bit 4-channel PNG (float32 bytes); "
                         f"found {image.dtype} with shape {image.shape}"
                         + (f" ({where})" if where else ""))
    _check_hw(image, hw, path, "distance image", where)
    return pngio.unpack_float32(image)


def read_release_mask(path: Path, hw, where: str = "") -> np.ndarray:
    """A mask as the release reads it (greyscale == 255 is valid), uint8 (h, w) in {0, 1}."""
    image = _read_any(path, where, cv2.IMREAD_GRAYSCALE)
    if image.dtype != np.uint8:
        raise ValueError(f"{path}: mask must be 8-bit; found {image.dtype}")
    _check_hw(image, hw, path, "mask", where)
    return (image == 255).astype(np.uint8)


# ---------------------------------------------------------------------------- the reader

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
        models = fmt.require(manifest, "camera_models", manifest_path, dict)
        samplers = fmt.require(manifest, "samplers", manifest_path, list)
        model_of: dict[str, str] = {}
        for k, s in enumerate(samplers):
            where = f"{manifest_path} samplers[{k}]"
            if not isinstance(s, dict):
                raise ValueError(f"{where}: must be an object; found {type(s).__name__}")
            if fmt.require(s, "mvs_main_cam_model_for_cam", where, bool):
                key = fmt.require(s, "mvs_cam_key", where, str)
                sampler = fmt.require(s, "sampler", where, dict)
                model_key = fmt.require(sampler, "cam_model_key", f"{where} sampler", str)
                if model_key not in models:
                    raise ValueError(f"{where}: sampler cam_model_key {model_key!r} is not in "
                                     f"camera_models; found {sorted(models)}")
                model_of[key] = model_key

        meta_path = self.root / METADATA
        meta = fmt.load_json(meta_path, "metadata")
        cams = fmt.require(meta, "cams", meta_path, list)
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
            frame = fmt.require(cams[k], "image_frame", where, str)
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
        self._rows = self._read_partition()
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
            entries = fmt.require(doc, field, path, list)
            found[field] = {}
            for k, e in enumerate(entries):
                where = f"{path} {field}[{k}]"
                cam = fmt.require(e, "raw_camera", where, str)
                found[field][cam] = self.root / fmt.require(e, "mask", where, str)
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

    def _read_partition(self) -> list[dict]:
        path = self.root / PARTITIONS
        doc = fmt.load_json(path, "data partitions")
        if self.split not in doc:
            raise ValueError(f"{path}: no partition {self.split!r}; found {sorted(doc)}")
        part = doc[self.split]
        if not isinstance(part, dict):
            raise ValueError(f"{path}: partition {self.split!r} must map environments to lists "
                             f"of trajectories; found {type(part).__name__}")
        rows = []
        for env, names in part.items():
            if not isinstance(names, list):
                raise ValueError(f"{path}: {self.split}[{env!r}] must be a list; found "
                                 f"{type(names).__name__}")
            for name in names:
                where = self.root / env / str(name)
                if where.is_dir():
                    meta_path = where / TRAJ_META
                    meta = fmt.load_json(meta_path, "trajectory metadata")
                    csv_name = fmt.require(meta, "selected_file_list", meta_path, str)
                    rows += self._read_csv(where / csv_name, where, f"{env}/{name}")
                elif str(name).endswith(".csv"):
                    rows += self._read_csv(where, self.root, f"{env}/{name}")
                else:
                    raise ValueError(f"{path}: {self.split}[{env!r}] lists {name!r}, which is "
                                     f"neither a trajectory folder ({where} does not exist) nor "
                                     f"a .csv file")
        return rows

    def _read_csv(self, path: Path, base: Path, trajectory: str) -> list[dict]:
        rgb_cols = [f"{n}{self.rgb_suffix}" for n in self.names]
        label_col = f"{RIG_KEY}{self.dist_suffix}"
        records = fmt.csv_records(path, rgb_cols + [label_col])
        dist_cols = [f"{n}{self.dist_suffix}" for n in self.names]
        has_dist = bool(records) and all(c in records[0][1] for c in dist_cols)
        out = []
        for line, row in records:
            def file(col):
                if not row[col]:
                    raise ValueError(f"{path} line {line}: empty field {col!r}")
                # The release splits on backslashes so Windows-written lists work too.
                return base.joinpath(*row[col].replace("\\", "/").split("/"))

            out.append({"csv": path, "line": line, "trajectory": trajectory,
                        "frame": len(out), "rgb": [file(c) for c in rgb_cols],
                        "label": file(label_col),
                        "dist": [file(c) for c in dist_cols] if has_dist else None})
        return out

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
