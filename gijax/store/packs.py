"""Resume packs: what the next piece of a long training needs, in one folder small enough to
commit.

A run folder (orbax checkpoints, TensorBoard files, samples) lives on one machine's disk and is
lost with it. A training that runs in pieces across machines therefore also keeps a *pack*, a
folder beside the code (``gijax train --pack DIR``), rewritten at every periodic checkpoint:

* ``state-<step>.npz``: every array of the training state (parameters, BatchNorm statistics,
  Adam's moments and count, the step; float32 as trained), keyed by its path in the state
  pytree (``jax.tree_util.keystr``). Adam's moments are kept because a restart without them
  is not free: Adam's first updates after a reset are full-size steps in the gradient's sign.
* ``metrics.jsonl``: the run's log up to that step (the learning curve across every piece,
  with the command, revision and host each piece recorded when it started).
* ``pack.json``: the step, the data stream's position, the training and network
  configurations, the candidate list, the command that continues the run, and the SHA-256
  of the state file it names.

The state file is written first under a new name, then ``pack.json`` is replaced atomically,
then older state files are removed: a reader sees the previous pack or the new one, never a
mix, and a state file that does not match its hash is refused with one line naming it.
A G16VV-cpu pack is about 12 MB.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any, Optional

import jax
import numpy as np

from gijax.checks import MISSING, bad_document_field, kind_of
from gijax.io.paths import atomic_path, write_text_atomic
from gijax.store.configs import METRICS_FILE

PACK_FILE = "pack.json"
FORMAT = "gijax-resume-pack"
VERSION = 1


@dataclasses.dataclass(frozen=True)
class Pack:
    """A pack read back: its ``pack.json`` document, the arrays by key, the log lines."""

    folder: Path
    meta: dict
    arrays: dict
    metrics: list

    @property
    def step(self) -> int:
        return int(self.meta["step"])


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def state_arrays(state: Any) -> dict[str, np.ndarray]:
    """``{keystr(path): numpy array}`` of every leaf of a state pytree (typed PRNG keys as
    their raw key data). Replicated device arrays are read from one local copy."""
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(state)[0]:
        if hasattr(leaf, "addressable_data"):
            leaf = leaf.addressable_data(0)
        if jax.dtypes.issubdtype(getattr(leaf, "dtype", None), jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        out[jax.tree_util.keystr(path)] = np.asarray(leaf)
    return out


def write_pack(folder: str | os.PathLike, state: Any, meta: dict,
               metrics_lines: list[str]) -> Path:
    """Write (or replace) the pack ``folder`` from a training ``state`` and ``meta`` (must hold
    ``step``; JSON-serialisable); ``metrics_lines`` are the run's log lines so far."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    step = int(meta["step"])
    name = f"state-{step:08d}.npz"
    arrays = state_arrays(state)
    with atomic_path(folder / name, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **arrays)
    write_text_atomic(folder / METRICS_FILE, "".join(line if line.endswith("\n") else line + "\n"
                                                     for line in metrics_lines))
    doc = {"format": FORMAT, "version": VERSION, **meta, "state_file": name,
           "state_sha256": _sha256(folder / name),
           "state_bytes": (folder / name).stat().st_size}
    write_text_atomic(folder / PACK_FILE, json.dumps(doc, indent=1) + "\n")
    for old in folder.glob("state-*.npz"):
        if old.name != name:
            old.unlink()
    return folder


def read_pack(folder: str | os.PathLike) -> Optional[Pack]:
    """The pack in ``folder``, or None when there is none; ValueError (one line naming the
    file) when it is damaged or of another format."""
    folder = Path(folder)
    doc_path = folder / PACK_FILE
    if not doc_path.is_file():
        return None
    try:
        meta = json.loads(doc_path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{doc_path}: not a readable resume pack ({exc})") from None
    if not isinstance(meta, dict):
        raise bad_document_field(doc_path, "format", f"{FORMAT!r} in a JSON object",
                                 kind_of(meta))
    if meta.get("format") != FORMAT:
        raise bad_document_field(doc_path, "format", repr(FORMAT), meta.get("format", MISSING))
    if meta.get("version") != VERSION:
        raise bad_document_field(doc_path, "version", str(VERSION), meta.get("version", MISSING))
    for field in ("step", "state_file", "state_sha256"):
        if field not in meta:
            raise bad_document_field(doc_path, field, "present", MISSING)
    name = str(meta["state_file"])
    if Path(name).name != name or not name.endswith(".npz"):
        raise bad_document_field(doc_path, "state_file", "a .npz file name in the pack", name)
    state_path = folder / name
    if not state_path.is_file():
        raise ValueError(f"{state_path}: the state file that {doc_path} names is missing")
    if _sha256(state_path) != meta["state_sha256"]:
        raise ValueError(f"{state_path}: its SHA-256 does not match {doc_path} (a damaged or "
                         f"partly copied pack)")
    with np.load(state_path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    metrics_path = folder / METRICS_FILE
    lines = metrics_path.read_text().splitlines(keepends=True) if metrics_path.is_file() else []
    return Pack(folder, meta, arrays, lines)


# One step of a ``jax.tree_util.keystr`` path: a dict key, a list index, or an attribute.
_KEY_STEP = re.compile(r"\['([^']*)'\]|\[(\d+)\]|\.(\w+)")


def model_variables(pack: Pack) -> dict[str, np.ndarray]:
    """The network's variables in ``pack`` (its parameters and its other variables: BatchNorm
    statistics, RNG stream states), keyed as a bundle's ``weights.npz`` keys them
    (``'features/stem/conv/kernel'``; see :func:`gijax.store.bundles.flatten_variables`).
    The optimiser's moments and the step are left out. ValueError (one line naming the state
    file) when the pack holds no network variables or a key of another form."""
    where = pack.folder / str(pack.meta.get("state_file", "?"))
    out = {}
    for key, arr in pack.arrays.items():
        steps = [m.groups() for m in _KEY_STEP.finditer(key)]
        if "".join(m.group(0) for m in _KEY_STEP.finditer(key)) != key:
            raise ValueError(f"{where}: array key {key!r} is not a pytree path")
        if not steps or steps[0][0] not in ("params", "rest"):
            continue
        # An nnx variable's array is its '.value'; every other step names a module or list.
        if steps[-1][2] == "value":
            steps = steps[:-1]
        if any(attr is not None for _, _, attr in steps):
            raise ValueError(f"{where}: array key {key!r} is not a network variable's path")
        out["/".join(name if name is not None else index for name, index, _ in steps[1:])] = arr
    if not out:
        raise ValueError(f"{where}: holds no network variables ('params' or 'rest')")
    return out


def restore_state(pack: Pack, abstract_state: Any) -> Any:
    """The pack's arrays in the structure of ``abstract_state`` (a pytree of
    ``jax.ShapeDtypeStruct`` or arrays), as numpy arrays (typed keys rewrapped); ValueError
    naming the first key that is missing or has another shape or dtype."""
    where = pack.folder / str(pack.meta["state_file"])
    leaves, treedef = jax.tree_util.tree_flatten_with_path(abstract_state)
    wanted = {jax.tree_util.keystr(p) for p, _ in leaves}
    extra = sorted(set(pack.arrays) - wanted)
    if extra:
        raise ValueError(f"{where}: holds arrays this training state has no place for, e.g. "
                         f"{extra[0]} (another network or optimiser)")
    out = []
    for path, leaf in leaves:
        key = jax.tree_util.keystr(path)
        if key not in pack.arrays:
            raise ValueError(f"{where}: array {key} is missing (another network or optimiser)")
        arr = pack.arrays[key]
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            out.append(jax.random.wrap_key_data(arr))
            continue
        if tuple(arr.shape) != tuple(leaf.shape) or arr.dtype != np.dtype(leaf.dtype):
            raise ValueError(f"{where}: array {key} expected {np.dtype(leaf.dtype)} "
                             f"{tuple(leaf.shape)}, found {arr.dtype} {tuple(arr.shape)}")
        out.append(arr)
    return jax.tree_util.tree_unflatten(treedef, out)


def is_pack(path: str | os.PathLike) -> bool:
    return (Path(path) / PACK_FILE).is_file()


def load_pack_model(folder: str | os.PathLike):
    """``(model, model_config, candidates)`` of the network in the pack ``folder`` at the pack's
    step, in eval mode (what a machine that has the committed pack but not the run folder can
    evaluate, export or start another training from); candidates are the run's list, (D,)
    float64 metres. ValueError (one line naming the file) when the pack is damaged or its
    variables do not fit its network."""
    from gijax.store.bundles import model_with_variables
    from gijax.store.configs import model_config_from_dict

    pack = read_pack(folder)
    if pack is None:
        raise FileNotFoundError(f"{Path(folder) / PACK_FILE}: no resume pack there")
    doc_path = pack.folder / PACK_FILE
    for field in ("model_config", "candidates"):
        if not isinstance(pack.meta.get(field), (dict, list)):
            raise bad_document_field(doc_path, field, "present", MISSING)
    try:
        mc = model_config_from_dict(pack.meta["model_config"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{doc_path}: field 'model_config' is not a network configuration "
                         f"({exc})") from None
    seed = int(pack.meta.get("train_config", {}).get("seed", 0))
    model = model_with_variables(mc, seed, model_variables(pack),
                                 pack.folder / str(pack.meta["state_file"]))
    return model, mc, np.asarray(pack.meta["candidates"], np.float64)
