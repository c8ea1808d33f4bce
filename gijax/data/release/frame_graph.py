"""The release's frame_graph.json: named frames linked by rigid transforms."""

from __future__ import annotations

import collections
import math
from pathlib import Path

import numpy as np

from gijax.data import format as fmt
from gijax.io.parsing import Where, floats

# Tolerance on |R^T R - I| of a frame graph's rotation_matrix.
RELEASE_ROTATION_TOL = 1e-3


def _num(spec, key, where) -> float:
    """A finite number (JSON's NaN and Infinity are refused)."""
    value = fmt.document_field(spec, key, where, (int, float))
    return float(floats(value, 1, key, Where(where), "one finite number")[0])


def _orientation(doc, where) -> np.ndarray:
    """A rotation matrix. The release uses a matrix as it is; one that is far from a rotation
    (beyond :data:`RELEASE_ROTATION_TOL`, looser than a calibration file's since these files
    print few digits) is refused, since every pose chained through it would be skewed."""
    kind = fmt.document_field(doc, "type", where, str)
    data = fmt.document_field(doc, "data", where, (list, dict))
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
    t = floats(fmt.document_field(doc, "position", where, list), 3, "position", Where(where),
               "3 numbers in metres")
    T = np.eye(4)
    T[:3, :3] = _orientation(fmt.document_field(doc, "orientation", where, dict),
                             f"{where} orientation")
    T[:3, 3] = t
    return T


class FrameGraph:
    """frame_graph.json: 4x4 transforms ``T_f0_f1`` (``p_f0 = T_f0_f1 @ p_f1``), metres."""

    def __init__(self, path: Path):
        self.path = path
        doc = fmt.load_json(path, "frame graph")
        frames = fmt.document_field(doc, "frames", path, list)
        typical = fmt.document_field(doc, "typical_poses", path, dict)
        transforms = fmt.document_field(doc, "transforms", path, list)
        self.edges: dict[str, dict[str, np.ndarray]] = collections.defaultdict(dict)
        for k, f in enumerate(frames):
            name = fmt.document_field(f, "name", f"{path} frames[{k}]", str)
            self.edges.setdefault(name, {})
        poses = {key: _pose(v, f"{path} typical_poses[{key!r}]") for key, v in typical.items()}
        for k, tr in enumerate(transforms):
            where = f"{path} transforms[{k}]"
            f0 = fmt.document_field(tr, "f0", where, str)
            f1 = fmt.document_field(tr, "f1", where, str)
            pose = fmt.document_field(tr, "pose", where, dict)
            kind = fmt.document_field(pose, "type", f"{where} pose", str)
            if kind == "create":
                T = _pose(pose, f"{where} pose")
            elif kind == "reference":
                key = fmt.document_field(pose, "key", f"{where} pose", str)
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
