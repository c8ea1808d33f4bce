"""The bundles shipped inside the package (``gijax/assets/NAME``), found by name.

Every ``--ckpt`` takes a path or the name of one of these bundles (``--ckpt G16VV-cpu``); a
path that exists wins over a name. ``gijax models`` lists them.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from gijax.store.bundles import is_bundle, read_provenance

ASSETS = Path(__file__).resolve().parents[1] / "assets"


def bundled_names() -> list[str]:
    """Names of the bundles in the package, sorted."""
    if not ASSETS.is_dir():
        return []
    return sorted(p.name for p in ASSETS.iterdir() if p.is_dir() and is_bundle(p))


def resolve_model_path(spec: str | os.PathLike) -> Path:
    """The folder ``--ckpt spec`` means: ``spec`` itself when it exists, else the bundled model
    of that name. FileNotFoundError listing the bundled names when it is neither."""
    path = Path(spec)
    if path.exists():
        return path
    if str(spec) in bundled_names():
        return ASSETS / str(spec)
    raise FileNotFoundError(f"{spec}: no such run folder or bundle, and no bundled model of that "
                            f"name ({_listing()})")


def _listing() -> str:
    names = bundled_names()
    return (f"bundled models: {', '.join(names) if names else 'none in this installation'}; "
            f"'gijax models' describes them")


@dataclasses.dataclass(frozen=True)
class BundledModel:
    """What ``gijax models`` shows of one bundled model."""

    name: str
    path: Path
    preset: str
    parameters: int
    candidates: list
    trained_on: str
    provenance: dict
    # The network settings in which the bundle departs from its named preset ({} when none).
    changed: dict = dataclasses.field(default_factory=dict)

    @property
    def limitations(self) -> str:
        return limitations(self.provenance)

    @property
    def compared(self) -> str:
        return held_out_comparison(self.provenance)


def parameter_count(config) -> int:
    """Trainable parameters of a network of ``config``, counted on its abstract shapes (no
    weights are made)."""
    import jax
    import numpy as np
    from flax import nnx

    from gijax.model import create_model

    abstract = nnx.eval_shape(lambda: create_model(config, 0))
    return int(sum(np.prod(x.shape) for x in jax.tree.leaves(nnx.state(abstract, nnx.Param))))


def preset_changes(config) -> dict:
    """The fields of a network ``config`` that differ from the preset it is named after, as
    ``{field: value}`` (a fine-tune can change the cost volume's size, for example); {} when it
    matches the preset or its name is not a preset."""
    from gijax.nn.presets import PRESETS

    preset = PRESETS.get(config.name)
    if preset is None:
        return {}
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
            if getattr(config, f.name) != getattr(preset, f.name)}


def trained_on(provenance: dict) -> str:
    """One line from a bundle's provenance: the data it was trained on, or where its weights
    came from."""
    if isinstance(provenance.get("trained_on"), str):
        return provenance["trained_on"]
    data = provenance.get("data")
    if isinstance(data, dict) and data:
        parts = []
        if "train_samples" in data:
            style = f" {data['style']}" if data.get("style") else ""
            parts.append(f"{data['train_samples']} rendered{style} scenes")
        if data.get("rig"):
            parts.append(f"on {data['rig']}")
        if data.get("camera_images"):
            parts.append(f"({data['camera_images']})")
        text = " ".join(parts) or ", ".join(f"{k} {v}" for k, v in data.items())
        if provenance.get("checkpoint"):
            text += f"; {provenance['checkpoint']}"
        return text
    if provenance.get("source"):
        return f"weights converted from {Path(str(provenance['source'])).name}"
    return "not recorded (no PROVENANCE.json)"


def held_out_comparison(provenance: dict) -> str:
    """One line from a bundle's provenance: its held-out MAE beside the classical baseline's on
    each test rig its targets name, and whether each target was met ('not recorded' when the
    provenance has no targets). The model's figure is the one its target judges (the training
    list's, else the recomputed list's)."""
    parts = []
    for target in provenance.get("targets") or []:
        if not isinstance(target, dict) or not isinstance(target.get("numbers"), dict):
            continue
        nums = target["numbers"]
        ours = nums.get("model", nums.get("model_spacing"))
        baseline = next(((k, v) for k, v in nums.items()
                         if str(k).startswith("RS-") and isinstance(v, (int, float))), None)
        if not isinstance(ours, (int, float)) or baseline is None:
            continue
        status = str(target.get("status", "")).lower()
        parts.append(f"{target.get('test', '?')} {ours:.4f} vs {baseline[0]} {baseline[1]:.4f}"
                     + (f" ({target['target']}: {status})" if target.get("target") else ""))
    if not parts:
        return "not recorded"
    return "held-out MAE (1/m, the paper's definition): " + "; ".join(parts)


def limitations(provenance: dict) -> str:
    """Where a bundle is expected to fail, as its provenance states it ('not stated' when it
    does not)."""
    text = provenance.get("limitations")
    return text if isinstance(text, str) and text else "not stated"


def describe_bundled(name: str) -> BundledModel:
    """The :class:`BundledModel` of bundle ``name`` (config and provenance only; no weights are
    loaded)."""
    from gijax.store.configs import read_run_config

    if name not in bundled_names():
        raise FileNotFoundError(f"{name}: no bundled model of that name ({_listing()})")
    path = ASSETS / name
    run = read_run_config(path)
    prov = read_provenance(path)
    return BundledModel(name=name, path=path, preset=run.model.name,
                        parameters=parameter_count(run.model), candidates=list(run.candidates),
                        trained_on=trained_on(prov), provenance=prov,
                        changed=preset_changes(run.model))
