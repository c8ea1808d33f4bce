"""Adapting a trained model's candidate list to a rig, the network frozen.

The candidates are data, not weights (:mod:`gijax.model`): a model runs with any list of its
length, and its outputs are differentiable in that list through the sweep grids and the
soft-argmax. :func:`adapt_candidates` optimises the list for one rig by Adam on the logits of
:mod:`gijax.candidates.parametrisation` (so every step is a valid list with the training list's
ends), on batches of that rig's data, by one of two losses:

* ``'supervised'``: the smooth L1 loss on inverse distance against the labels
  (:func:`gijax.train.losses.smooth_l1_loss`, the release's units), whatever loss the model
  was trained with: the error the tables report is the regressed inverse distance;
* ``'photometric'``: no labels (so it also serves real captures): each predicted panorama point
  is projected into every camera's surrogate image and the cameras' colours there are compared
  (:func:`gijax.train.unlabeled.photometric_loss`, masks respected). The right distance
  makes them agree.

The model stays in eval mode (BatchNorm running statistics) and is never changed. The pure
piece (:func:`adaptation_loss`) is traceable; :func:`adapt_candidates` is
the loop at the edge: progress bar, atomic checkpoints, resume.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from gijax.checks import bad_field
from gijax.candidates.parametrisation import candidates_from_logits, logits_from_candidates
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig
from gijax.model import OmniStereoNet, model_grids, model_panorama
from gijax.train.losses import smooth_l1_loss
from gijax.train.step import split_model
from gijax.train.unlabeled import photometric_loss

Array = jax.Array

LOSSES = ("supervised", "photometric")


def adaptation_loss(kind: str, model: OmniStereoNet, logits: Array, batch: dict, rig: Rig,
                    d_min: float, d_max: float) -> Array:
    """The loss of ``kind`` ('supervised' or 'photometric') for the list of ``logits`` on one
    batch (the loader's: ``surrogates``, ``masks``, and ``distance`` / ``valid`` labels
    for the supervised loss), ``model`` in eval mode on its own panorama; traceable."""
    cand = candidates_from_logits(logits, d_min, d_max)
    surrogates = batch["surrogates"]
    grids = model_grids(model.config, rig, cand.astype(surrogates.dtype))
    out = model(surrogates, batch["masks"], grids)
    if kind == "supervised":
        return smooth_l1_loss(out["inv_distance"], batch["distance"], batch["valid"], cand)
    if kind == "photometric":
        cfg = model.config
        return photometric_loss(surrogates, batch["masks"], rig, out["inv_distance"],
                                model_panorama(cfg),
                                Panorama.hemisphere(*surrogates.shape[2:4]))
    raise ValueError(f"adaptation loss {kind!r}; expected one of {LOSSES}")


@dataclasses.dataclass(frozen=True)
class AdaptConfig:
    """How to adapt: ``loss`` ('supervised' or 'photometric'), Adam steps at learning rate
    ``lr`` on the logits, ``batch_size`` samples per step, ``seed`` (data order), a checkpoint
    every ``checkpoint_every`` steps."""

    loss: str = "supervised"
    steps: int = 200
    lr: float = 0.05
    batch_size: int = 4
    seed: int = 0
    checkpoint_every: int = 25

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise bad_field("AdaptConfig", "loss", f"one of {LOSSES}", self.loss)
        for field in ("steps", "batch_size", "checkpoint_every"):
            if int(getattr(self, field)) < 1:
                raise bad_field("AdaptConfig", field, ">= 1", getattr(self, field))
        if not self.lr > 0:
            raise bad_field("AdaptConfig", "lr", "> 0", self.lr)


@dataclasses.dataclass
class AdaptResult:
    """``candidates`` (N,) metres after adaptation, ``initial`` (N,), ``history`` of
    ``{'step', 'loss'}`` (the loss of each step's batch before its update) and the files
    written."""

    candidates: np.ndarray
    initial: np.ndarray
    history: list
    files: dict


def state_folder(out_file) -> Path:
    """The folder beside ``out_file`` that holds the adaptation's checkpoint and curve."""
    out = Path(out_file)
    return out.with_name(out.stem + ".adapt")


def adapt_candidates(model: OmniStereoNet, rig: Rig, make_batches: Callable, initial,
                     config: AdaptConfig, out_file: str | os.PathLike | None = None, *,
                     record: Optional[dict] = None, progress: bool = True,
                     log: Optional[Callable[[str], None]] = None) -> AdaptResult:
    """Optimise ``model``'s candidate list for ``rig``, the network frozen.

    Args:
      model: a trained :class:`OmniStereoNet` (not modified; run in eval mode).
      rig: the rig the batches show, at the model's image size (its panorama frame is used).
      make_batches: ``make(state | None) -> loader`` yielding the training loader's batches
        (surrogate images, masks, labels) forever, with ``state()`` to resume from
        (:func:`gijax.train.sources.dataset_stream_factory`).
      initial: the starting list (N,) metres, N = the model's candidate count; its ends stay.
      config: :class:`AdaptConfig`.
      out_file: the list's JSON file (``{"candidates": [...], ...}``, read by every
        ``--candidates FILE``); the checkpoint, the loss curve (CSV and PNG) and the record
        go to :func:`state_folder` beside it. Rerunning with the same settings resumes.
      record: extra provenance stored in the record (command, model, data).
      progress, log: progress bar, and a callback for one-line notes.
    """
    from tqdm import tqdm

    from gijax.io.paths import atomic_path, write_text_atomic

    say = log or (lambda _line: None)
    cfg = model.config
    initial = np.asarray(initial, np.float64)
    if initial.shape != (cfg.num_candidates,):
        raise ValueError(f"model {cfg.name!r} needs {cfg.num_candidates} candidates; the "
                         f"initial list has shape {initial.shape}")
    d_min, d_max = float(initial[0]), float(initial[-1])
    logits = logits_from_candidates(jnp.asarray(initial, jnp.float32), d_min, d_max)
    tx = optax.adam(config.lr)
    opt = tx.init(logits)
    step0, history, stream_state = 0, [], None
    folder = state_folder(out_file) if out_file is not None else None
    settings = {"config": dataclasses.asdict(config), "initial": initial.tolist(),
                "model": cfg.name}
    if folder is not None and (folder / "state.npz").is_file():
        saved = json.loads((folder / "record.json").read_text())
        if saved.get("settings") != settings:
            raise ValueError(f"{folder} holds an adaptation with other settings "
                             f"({saved.get('settings')}); delete it or choose another --out")
        with np.load(folder / "state.npz") as z:
            logits = jnp.asarray(z["logits"])
            opt = jax.tree.unflatten(jax.tree.structure(opt),
                                     [jnp.asarray(z[f"opt{i}"]) for i in
                                      range(len(jax.tree.leaves(opt)))])
        step0 = int(saved["step"])
        history = saved["history"]
        stream_state = saved.get("stream")
        say(f"{folder}: resuming after step {step0}")

    # The trainer's split, on a copy: ``model`` itself keeps its mode.
    _, eval_def, params, rest = split_model(nnx.merge(*nnx.split(model)))
    compiled = _adapt_step(eval_def, config.loss, d_min, d_max, config.lr)

    def step_fn(lg, opt_state, batch):
        return compiled(params, rest, rig, lg, opt_state, batch)

    def save(step: int, loader) -> None:
        if folder is None:
            return
        folder.mkdir(parents=True, exist_ok=True)
        arrays = {"logits": np.asarray(logits)}
        arrays.update({f"opt{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(opt))})
        with atomic_path(folder / "state.npz") as tmp:
            np.savez(tmp, **arrays)
        doc = {"settings": settings, "step": step, "history": history,
               "stream": loader.state() if loader is not None else None,
               "record": record or {}}
        write_text_atomic(folder / "record.json", json.dumps(doc, indent=2))
        write_text_atomic(folder / "curve.csv", "step,loss\n" + "".join(
            f"{h['step']},{h['loss']:.8g}\n" for h in history))

    # Committed to the device like the step's outputs, so the first call compiles the only
    # program.
    dev = jax.local_devices()[0]
    logits, opt = jax.device_put((logits, opt), dev)
    loader = make_batches(stream_state) if step0 < config.steps else None
    try:
        with tqdm(total=config.steps, initial=step0, desc=f"adapt ({config.loss})",
                  unit="step", disable=not progress) as bar:
            for step in range(step0, config.steps):
                batch = next(loader)
                feed = {k: jnp.asarray(batch[k]) for k in ("surrogates", "masks",
                                                          "distance", "valid")}
                logits, opt, loss = step_fn(logits, opt, feed)
                loss = float(loss)
                if not math.isfinite(loss):
                    raise FloatingPointError(f"adaptation loss is {loss} at step {step}")
                history.append({"step": step, "loss": loss})
                bar.set_postfix(loss=f"{loss:.4f}")
                bar.update(1)
                if (step + 1) % config.checkpoint_every == 0 or step + 1 == config.steps:
                    save(step + 1, loader)
    finally:
        if loader is not None and hasattr(loader, "close"):
            loader.close()
    final = np.asarray(candidates_from_logits(logits, d_min, d_max), np.float64)
    files = {}
    if out_file is not None:
        out = Path(out_file)
        doc = {"candidates": final.tolist(), "initial": initial.tolist(),
               "loss": config.loss, "steps": config.steps,
               "final_loss": history[-1]["loss"] if history else None,
               "state": str(folder), **(record or {})}
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out, json.dumps(doc, indent=2))
        files["list"] = str(out)
        files["state"] = str(folder)
        if history:
            files["curve"] = _plot_curve(folder / "curve.png", history, initial, final,
                                         config.loss)
    return AdaptResult(final, initial, history, files)


_STEPS: dict = {}


def _adapt_step(eval_def, kind: str, d_min: float, d_max: float, lr: float):
    """The jitted Adam step on the logits, one per (network, loss, range, rate) in a process:
    a resumed or repeated adaptation (another rig, another list) compiles nothing new."""
    key = (eval_def, kind, d_min, d_max, lr)
    if key not in _STEPS:
        tx = optax.adam(lr)

        @jax.jit
        def step(params, rest, rig, logits, opt_state, batch):
            def loss_fn(lg):
                net = nnx.merge(eval_def, params, jax.tree.map(lambda x: x, rest))
                return adaptation_loss(kind, net, lg, batch, rig, d_min, d_max)

            loss, grad = jax.value_and_grad(loss_fn)(logits)
            updates, opt_state = tx.update(grad, opt_state, logits)
            return optax.apply_updates(logits, updates), opt_state, loss

        _STEPS[key] = step
    return _STEPS[key]


def _plot_curve(path: Path, history: list, initial: np.ndarray, final: np.ndarray,
                kind: str) -> str:
    """Loss per step, and the two lists in inverse distance."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gijax.io.paths import save_figure_atomic

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    steps = [h["step"] for h in history]
    a.plot(steps, [h["loss"] for h in history], lw=0.8)
    a.set_xlabel("step")
    a.set_ylabel(f"{kind} loss")
    a.set_title("adaptation loss (each step's batch)")
    for lst, label, mark in ((initial, "initial", "o"), (final, "adapted", "x")):
        b.plot(1.0 / lst, np.arange(len(lst)), mark, label=label)
    b.set_xlabel("inverse distance (1/m)")
    b.set_ylabel("candidate index")
    b.legend()
    b.set_title("candidate lists")
    fig.tight_layout()
    try:
        save_figure_atomic(fig, path, dpi=110, format="png")
    finally:
        plt.close(fig)
    return str(path)
