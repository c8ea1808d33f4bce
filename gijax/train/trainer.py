"""The training loop: data-parallel steps, logging, validation, checkpoints and resume.

Side effects (files, progress bar) live here; the numerical work is the jitted step of
:mod:`gijax.train.step`. Only process 0 writes logs, sample images and the run config; every
process takes part in the (collective) checkpoint saves. Validation runs on each process's
first local device over the whole validation set (every process computes the same numbers, so
no communication is needed to rank checkpoints).
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import time
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gijax.candidates.parametrisation import logits_from_candidates
from gijax.evaluate.labels import usable_label
from gijax.evaluate.loop import evaluate_predictions
from gijax.evaluate.prediction import Prediction
from gijax.geometry.rig import Rig
from gijax.model import model_rig
from gijax.io.lock import FolderLock
from gijax.train import step as S
from gijax.io.paths import write_png_atomic, write_text_atomic
from gijax.store.configs import CONFIG_FILE, model_config_from_dict, model_config_to_dict
from gijax.store.checkpoints import CheckpointStore
from gijax.train.config import TrainConfig, load_run_config, save_run_config
from gijax.train.sources import RIG_KEY

METRICS_FILE = "metrics.jsonl"
# The learned candidate list of a run with TrainConfig.learn_candidates (a --candidates FILE).
LEARNED_FILE = "candidates.json"


def init_distributed(coordinator: Optional[str], num_processes: Optional[int],
                     process_id: Optional[int]) -> None:
    """``jax.distributed.initialize`` for multi-host runs (no-op without a coordinator).

    ``coordinator`` is 'host:port' of process 0; every process passes the same address and
    process count and its own id. CPU processes exchange data through gloo.
    """
    if not coordinator:
        return
    if num_processes is None or process_id is None:
        raise ValueError("--coordinator needs --num-processes and --process-id as well")
    if not 0 <= process_id < num_processes:
        raise ValueError(f"--process-id must be in [0, {num_processes}); found {process_id}")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                               process_id=process_id)


def training_candidates(config: TrainConfig, rig: Optional[Rig]) -> np.ndarray:
    """The candidate list (metres) a run trains with: explicit, or the preset's kind.

    GI presets train with the closed form at the paper's training baseline (the released G8 /
    G16 lists), exactly as the paper's models did; rig-aware lists are for adapting a trained
    model to another rig (``--candidates rig`` at evaluation and inference).
    """
    mc = config.model_config()
    if config.candidates is not None:
        cand = np.asarray(config.candidates, np.float64)
    else:
        from gijax.candidates import candidates_for

        kind = "gi-closed" if mc.candidates == "gi" else "ev"
        cand = np.asarray(candidates_for(kind, mc.num_candidates, rig=rig, d_min=mc.d_min,
                                         d_max=mc.d_max), np.float64)
    if cand.shape != (mc.num_candidates,):
        raise ValueError(f"preset {config.preset!r} needs {mc.num_candidates} candidates; "
                         f"found {cand.shape[0] if cand.ndim == 1 else cand.shape}")
    from gijax.candidates.validation import check_candidates

    return check_candidates(cand)


class Trainer:
    """Trains one run folder; resumes from its newest readable checkpoint when there is one.

    Args:
      config: the training configuration.
      run_dir: the run folder (created if needed).
      rig: the training rig (sweep geometry; also the default for GI candidates), or a
        sequence of rigs, one per training dataset: batches then carry ``rig_index``
        (:class:`gijax.train.sources.MixedStream`) and the first rig sets the GI candidates.
      make_train_stream: ``make(state | None) -> stream`` (see :mod:`gijax.train.sources`).
      make_val_batches: ``() -> iterable of batches`` (whole validation set), or None.
      rig_name: recorded in the run config.
      progress: show a tqdm progress bar.
      devices: devices of the data-parallel mesh (default: all devices of all processes).
      val_rig: the validation data's rig (default: the training rig).
    """

    def __init__(self, config: TrainConfig, run_dir, rig: Rig | Sequence[Rig],
                 make_train_stream: Callable,
                 make_val_batches: Optional[Callable[[], Iterable[dict]]] = None,
                 rig_name: str = "", progress: bool = True, devices=None,
                 val_rig: Optional[Rig] = None, invocation: Optional[dict] = None):
        from gijax.model import create_model

        self.config = config
        # What started this piece of the run (command, code revision, ...): logged with the
        # start or resume event, so a training split over several runs says how each went.
        self.invocation = dict(invocation or {})
        self.mc = config.model_config()
        self.run_dir = Path(run_dir)
        rigs = list(rig) if isinstance(rig, (list, tuple)) else [rig]
        rig = rigs[0]
        self.rigs = [model_rig(r) for r in rigs]
        self.rig = self.rigs[0]
        self.val_rig = self.rig if val_rig is None else model_rig(val_rig)
        self.make_train_stream = make_train_stream
        self.make_val_batches = make_val_batches
        self.progress = progress
        self.is_main = jax.process_index() == 0
        self.mesh = S.make_mesh(devices)
        ndev = self.mesh.devices.size
        micro = config.batch_size // config.grad_accum
        if micro % ndev:
            raise ValueError(f"batch size {config.batch_size} / grad_accum {config.grad_accum} = "
                             f"{micro} samples per micro-batch cannot be split over {ndev} devices")
        if config.batch_size % jax.process_count():
            raise ValueError(f"batch size {config.batch_size} cannot be split over "
                             f"{jax.process_count()} processes")
        # A bad candidate list is found before the run folder exists, so it leaves none behind.
        if not (self.run_dir / CONFIG_FILE).exists():
            training_candidates(config, rig)
        check_run_folder(self.run_dir)
        fresh = not self.run_dir.exists()
        self.run_dir.mkdir(parents=True, exist_ok=True)
        # One writer per run folder; process 0 holds the lock for the processes of its run.
        self._lock = FolderLock(self.run_dir, "run folder") if self.is_main else None
        if self._lock is not None:
            self._lock.acquire()
        try:
            self.candidates = self._resolve_candidates(rig, rig_name)

            model = create_model(self.mc, config.seed)
            self.train_def, self.eval_def, params, rest = S.split_model(model)
            self.tx = S.make_optimizer(config)
            self.lr_fn = S.learning_rate_schedule(config)
            # A learned list keeps the training list's ends; its logits get their own Adam.
            self.d_range = (float(self.candidates[0]), float(self.candidates[-1]))
            self.tx_cand = optax.adam(config.candidates_lr) if config.learn_candidates else None
            logits0 = (logits_from_candidates(jnp.asarray(self.candidates, jnp.float32))
                       if config.learn_candidates else None)
            state = S.init_state(params, rest, self.tx, logits0, self.tx_cand)
            self.store = CheckpointStore(self.run_dir, config.keep,
                                         config.best_metric if config.keep_best else None,
                                         config.best_mode)
            abstract = S.abstract_like(state, S.replicated(self.mesh))
            restored = self.store.restore_latest(abstract, self._check_meta)
            pack = self._newer_pack(None if restored is None else int(restored[1]["step"]))
            if pack is not None:
                from gijax.store.packs import restore_state

                self.state = S.place_state(restore_state(pack, abstract), self.mesh)
                self.start_step, self.stream_state = pack.step, pack.meta.get("stream")
                if self.is_main:
                    write_text_atomic(self.run_dir / METRICS_FILE, "".join(pack.metrics))
            elif restored is None:
                if config.init_from:
                    params, rest = self._initial_variables(params, rest)
                    state = S.init_state(params, rest, self.tx, logits0, self.tx_cand)
                self.state = S.place_state(state, self.mesh)
                self.start_step, self.stream_state = 0, None
            else:
                self.state, meta = restored
                self.start_step, self.stream_state = int(meta["step"]), meta.get("stream")
            self._step = S.jit_train_step(
                S.build_train_step(self.train_def, self.tx, self.mc.loss, config.grad_accum,
                                   config.bf16, self.tx_cand, self.d_range), self.mesh)
            self._eval = jax.jit(S.build_eval_forward(self.eval_def))
            self._cand = jnp.asarray(self.candidates, jnp.float32)
            if config.learn_candidates:
                self._sync_candidates()
            self.history: list[dict] = []
            self._tb = None
            self._stream = None
            self._perturb = None
        except BaseException:
            if self._lock is not None:
                self._lock.release()
            if fresh and self.is_main:       # nothing was trained: leave no folder behind
                shutil.rmtree(self.run_dir, ignore_errors=True)
            raise

    # ----------------------------------------------------------------- run folder checks
    def _resolve_candidates(self, rig: Rig, rig_name: str) -> np.ndarray:
        path = self.run_dir / CONFIG_FILE
        if path.exists():
            old_cfg, old_mc, old_cand = load_run_config(self.run_dir)
            if old_cfg.preset != self.config.preset:
                raise ValueError(f"run folder {self.run_dir} was trained with preset "
                                 f"{old_cfg.preset!r}; resuming it with preset "
                                 f"{self.config.preset!r} is not possible (use a new --out)")
            if old_mc.num_candidates != self.mc.num_candidates or len(old_cand) != self.mc.num_candidates:
                raise ValueError(f"run folder {self.run_dir} was trained with {len(old_cand)} "
                                 f"candidates; this configuration has {self.mc.num_candidates}")
            # The conv lowering changes how the same weights are computed, not the weights: a
            # run may resume under another one.
            if dataclasses.replace(old_mc, conv3d=self.mc.conv3d) != self.mc:
                raise ValueError(f"run folder {self.run_dir} was trained with another network "
                                 f"configuration ({old_mc}); this one is {self.mc}")
            if old_cfg.learn_candidates != self.config.learn_candidates:
                say = "learned" if old_cfg.learn_candidates else "fixed"
                raise ValueError(f"run folder {self.run_dir} was trained with a {say} candidate "
                                 f"list; resume it with the same --learn-candidates setting")
            cand = np.asarray(old_cand, np.float64)
            if self.config.candidates is not None and not np.allclose(self.config.candidates, cand):
                raise ValueError(f"run folder {self.run_dir} was trained with candidates "
                                 f"{cand.tolist()}; this configuration asks for "
                                 f"{list(self.config.candidates)}")
        else:
            cand = training_candidates(self.config, rig)
        if self.is_main:
            save_run_config(self.run_dir, self.config, cand, rig_name)
        return cand

    def _initial_variables(self, params, rest):
        """``(params, rest)`` of the model ``config.init_from`` names, checked against this
        run's network: same configuration (up to the conv lowering) and variable shapes."""
        from flax import nnx

        from gijax.store import load_model
        from gijax.store.runs import check_param_shapes, named_shapes

        spec = self.config.init_from
        model, mc, _ = load_model(spec)
        # Fields that resize the cost volume and output, not any weight: a model trained at one
        # resolution starts a run at another (e.g. G16VV-cpu -> G16VV-cpu-fine).
        resolution = {"name", "conv3d", "cost_hw", "output_hw", "output_stride"}
        same = {f.name: getattr(self.mc, f.name) for f in dataclasses.fields(mc)
                if f.name in resolution}
        if dataclasses.replace(mc, **same) != self.mc:
            diff = {f.name: (getattr(mc, f.name), getattr(self.mc, f.name))
                    for f in dataclasses.fields(mc) if f.name not in resolution
                    and getattr(mc, f.name) != getattr(self.mc, f.name)}
            raise ValueError(f"init_from {spec!r}: its network configuration differs from this "
                             f"run's in " + ", ".join(f"{k} (its {a!r}, this run's {b!r})"
                                                      for k, (a, b) in diff.items()))
        model.train()
        _, new_params, new_rest = nnx.split(model, nnx.Param, ...)
        for name, new, old in (("parameters", new_params, params), ("variables", new_rest, rest)):
            check_param_shapes(Path(str(spec)), named_shapes(new), named_shapes(old),
                               f"{self.config.preset} ({name})")
        return new_params, new_rest

    def _newer_pack(self, checkpoint_step: Optional[int]):
        """The run's resume pack when it is ahead of the run folder's newest checkpoint (at
        ``checkpoint_step``, None without one) and belongs to this run; else None."""
        if not self.config.pack:
            return None
        from gijax.store.packs import read_pack

        pack = read_pack(self.config.pack)
        if pack is None or (checkpoint_step is not None and pack.step <= checkpoint_step):
            return None
        where = Path(self.config.pack)
        self._check_meta(pack.meta)
        # Read as a config, so that a field added since the pack was written counts at its
        # default (the network it describes is the same one).
        try:
            found = model_config_to_dict(model_config_from_dict(pack.meta.get("model_config", {})))
        except (TypeError, ValueError):
            found = pack.meta.get("model_config", {})
        expected = model_config_to_dict(dataclasses.replace(self.mc, conv3d="auto"))
        if dict(found, conv3d="auto") != expected:
            diff = sorted(k for k in expected if found.get(k) != expected[k] and k != "conv3d")
            raise ValueError(f"resume pack {where}: its network configuration differs from "
                             f"this run's in {', '.join(diff) or 'its fields'}")
        if not np.allclose(pack.meta["candidates"], self.candidates, rtol=1e-9, atol=0):
            raise ValueError(f"resume pack {where}: trained with candidates "
                             f"{pack.meta['candidates']}; this run's are "
                             f"{[float(c) for c in self.candidates]}")
        return pack

    def _write_pack(self, step: int, stream_state) -> None:
        """Rewrite the resume pack (process 0) with the state, the stream and the log."""
        if not (self.config.pack and self.is_main):
            return
        from gijax.store.packs import write_pack

        meta = {**self._meta(step, stream_state), "train_config": self.config.to_dict(),
                "model_config": model_config_to_dict(self.mc),
                "command": self.invocation.get("command"), "git": self.invocation.get("git")}
        path = self.run_dir / METRICS_FILE
        lines = path.read_text().splitlines(keepends=True) if path.exists() else []
        write_pack(self.config.pack, self.state, meta, lines)

    def _check_meta(self, meta: dict) -> None:
        if meta.get("preset") != self.config.preset:
            raise ValueError(f"checkpoint step {meta.get('step')} in {self.run_dir} belongs to "
                             f"preset {meta.get('preset')!r}, not {self.config.preset!r}")
        if len(meta.get("candidates", [])) != self.mc.num_candidates:
            raise ValueError(f"checkpoint step {meta.get('step')} in {self.run_dir} has "
                             f"{len(meta.get('candidates', []))} candidates; this configuration "
                             f"has {self.mc.num_candidates}")

    def _sync_candidates(self) -> None:
        """With a learned list: the current list from the state, as numpy and on device."""
        logits = np.asarray(self.state["cand_logits"].addressable_data(0))
        self._cand = S.state_candidates({"cand_logits": jnp.asarray(logits)}, self.d_range)
        self.current_candidates = np.asarray(self._cand, np.float64)

    def _write_candidates(self, step: int) -> None:
        """candidates.json: the learned list now (and the list it started from)."""
        if not self.is_main:
            return
        doc = {"step": step, "candidates": self.current_candidates.tolist(),
               "initial": [float(c) for c in self.candidates],
               "learned": True}
        write_text_atomic(self.run_dir / LEARNED_FILE, json.dumps(doc, indent=2))

    def _meta(self, step: int, stream_state) -> dict:
        meta = {"step": step, "preset": self.config.preset,
                "candidates": [float(c) for c in self.candidates], "stream": stream_state,
                "time": time.time()}
        if self.config.learn_candidates:
            meta["learned_candidates"] = self.current_candidates.tolist()
        return meta

    # ----------------------------------------------------------------- logging
    def _log(self, record: dict) -> None:
        self.history.append(record)
        if not self.is_main:
            return
        with open(self.run_dir / METRICS_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")
        if self._tb is None:
            from gijax.io.events import EventWriter

            self._tb = EventWriter(self.run_dir / "tb")
        prefix = record.get("split", "train")
        self._tb.scalars(record["step"], {f"{prefix}/{k}": v for k, v in record.items()
                                          if isinstance(v, (int, float)) and k != "step"})
        self._tb.flush()

    # ----------------------------------------------------------------- validation
    def local_variables(self):
        """Parameters and other variables on this process's first local device."""
        first = lambda x: x.addressable_data(0)  # noqa: E731 - replicated: any copy will do
        return jax.tree.map(first, self.state["params"]), jax.tree.map(first, self.state["rest"])

    def predict_batch(self, batch: dict, params=None, rest=None) -> dict:
        if params is None:
            params, rest = self.local_variables()
        return self._eval(params, rest, jnp.asarray(batch["surrogates"], jnp.float32),
                          jnp.asarray(batch["masks"], jnp.float32), self.val_rig, self._cand)

    def validate(self, step: int) -> Optional[dict]:
        """Metrics over the validation set (None without one); writes sample images."""
        if self.make_val_batches is None:
            return None
        params, rest = self.local_variables()

        def predict(batch):
            inv = self.predict_batch(batch, params, rest)["inv_distance"]
            # The network gives an estimate at every pixel.
            return Prediction(inv_distance=inv, valid=jnp.ones(inv.shape, bool))

        result = evaluate_predictions(self.make_val_batches(), predict, self._cand,
                                      metric_sets=("gijax",), keep=self.config.sample_images,
                                      name="the validation data")
        if self.is_main:
            self._write_samples(step, [(p.inv_distance, d) for p, d in result.examples])
        return result.metrics["gijax"]

    def _write_samples(self, step: int, samples) -> None:
        from gijax.viz.colormap import colorize

        lo, hi = 1.0 / float(self.candidates[-1]), 1.0 / float(self.candidates[0])
        folder = self.run_dir / "samples"
        folder.mkdir(exist_ok=True)
        for i, (inv, dist) in enumerate(samples):
            gt = 1.0 / np.where(usable_label(dist), dist, np.inf)
            gap = np.full((4, inv.shape[1], 3), 255, np.uint8)
            rgb = np.concatenate([colorize(inv, lo, hi), gap, colorize(gt, lo, hi)], axis=0)
            write_png_atomic(folder / f"step{step:07d}_sample{i}.png", rgb)
            if self._tb is not None:
                self._tb.image(step, f"val/prediction_above_label_below/{i}", rgb)

    # ----------------------------------------------------------------- loop
    def fit(self, steps: Optional[int] = None) -> list[dict]:
        """Train until ``steps`` (default ``config.steps``) optimiser updates are done."""
        cfg = self.config
        total = cfg.steps if steps is None else int(steps)
        if self._stream is None:
            self._stream = self.make_train_stream(self.stream_state)
        stream = self._stream
        step = self.start_step
        if self.is_main:
            # A killed run may have logged steps after its last checkpoint (or before its
            # first one); they are computed and logged again from here.
            drop_logs_after(self.run_dir, step)
        if step > 0:
            self._log({"step": step, "event": "resumed", **self.invocation})
        elif self.invocation:
            self._log({"step": 0, "event": "started", **self.invocation})
        bar = None
        if self.progress and self.is_main:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=step, unit="step", dynamic_ncols=True)
        self._t_last, n_last = time.perf_counter(), 0
        # Host seconds spent getting batches since the last record. Steps are dispatched
        # asynchronously, so this overlaps the previous step's computation: it bounds from
        # above the time the step stood still for data, and grows towards the step time when
        # the loader falls behind.
        self._waited = 0.0
        # The loss of a step is read once the next step is dispatched, so that the device
        # computes while the host places the next batch; it is read at once before a
        # checkpoint or a validation (a non-finite loss is never saved) and at the end.
        pending = None
        try:
            while step < total:
                t_wait = time.perf_counter()
                local = next(stream)
                self._waited += time.perf_counter() - t_wait
                rig = self.rigs[local.get(RIG_KEY, 0)]
                if cfg.calibration_error_deg:
                    rig = self.calibrated_rig(rig, step)
                self.state, out = self._step(self.state, S.place_batch(local, self.mesh),
                                             rig, self._cand)
                step += 1
                n_last += cfg.batch_size
                if pending is not None:
                    self._record(*pending, bar)
                    pending = None
                if step % cfg.log_every == 0 or step == total:
                    pending, n_last = (step, out, n_last), 0
                if bar is not None:
                    bar.update(1)
                last = step == total
                saving = (cfg.ckpt_every and step % cfg.ckpt_every == 0) or last
                validating = ((cfg.val_every and step % cfg.val_every == 0)
                              or (last and self.make_val_batches))
                if pending is not None and (saving or validating):
                    self._record(*pending, bar)
                    pending = None
                if cfg.learn_candidates and (saving or validating):
                    self._sync_candidates()
                    self._write_candidates(step)
                if saving:
                    self.store.save(step, self.state, self._meta(step, stream.state()))
                if validating:
                    metrics = self.validate(step)
                    if metrics is not None:
                        record = {"step": step, "split": "val", **metrics}
                        if cfg.learn_candidates:   # logged beside the numbers, not ranked
                            record["candidates"] = self.current_candidates.tolist()
                        self._log(record)
                        if cfg.keep_best:
                            self.store.maybe_save_best(step, self.state,
                                                       self._meta(step, stream.state()), metrics)
                if saving:     # after the validation, so the pack's log holds it
                    self._write_pack(step, stream.state())
        finally:
            if bar is not None:
                bar.close()
            if self._tb is not None:
                self._tb.close()
                self._tb = None
        self.start_step = step
        return self.history

    def _record(self, step: int, out: dict, samples: int, bar) -> None:
        """Log the loss of ``step`` (``samples`` trained since the previous record)."""
        loss = float(out["loss"])
        if not math.isfinite(loss):
            raise FloatingPointError(f"training loss became {loss} at step {step}")
        now = time.perf_counter()
        elapsed = max(now - self._t_last, 1e-9)
        rate = samples / elapsed
        waited, self._waited = self._waited, 0.0
        self._t_last = now
        self._log({"step": step, "loss": loss, "grad_norm": float(out["grad_norm"]),
                   "lr": float(self.lr_fn(step - 1)), "samples_per_s": rate,
                   "data_wait_fraction": min(waited / elapsed, 1.0)})
        if bar is not None:
            bar.set_postfix(loss=f"{loss:.4f}", samples_s=f"{rate:.2f}")

    def calibrated_rig(self, rig: Rig, step: int) -> Rig:
        """The rig the network is told about at ``step`` under ``calibration_error_deg``: each
        camera turned by a random rotation (:func:`gijax.data.calibration_error.perturb_rig`,
        rotation only: the loader's resampling fixes the intrinsics), drawn from the seed and
        the step, so a resumed run draws the same errors."""
        if self._perturb is None:
            from gijax.data.calibration_error import CalibrationError, perturb_rig

            error = CalibrationError(rotation_deg=self.config.calibration_error_deg, focal=0.0,
                                     centre=0.0)
            self._perturb = jax.jit(lambda key, r: perturb_rig(key, r, error))
        key = jax.random.fold_in(jax.random.PRNGKey(self.config.seed), 0x6361 + step)
        return self._perturb(key, rig)

    def close(self) -> None:
        if self._stream is not None:
            getattr(self._stream, "close", lambda: None)()
            self._stream = None
        self.store.close()
        if self._lock is not None:
            self._lock.release()


def check_run_folder(run_dir: Path) -> None:
    """ValueError, before anything is written, when ``run_dir`` exists and holds files but is
    not a run folder (no ``config.json``): a dataset or any other folder is never trained
    into."""
    from gijax.io.lock import LOCK_FILE

    if not run_dir.is_dir() or (run_dir / CONFIG_FILE).exists():
        return
    others = sorted(p.name for p in run_dir.iterdir() if p.name != LOCK_FILE)
    if others:
        raise ValueError(f"run folder {run_dir}: exists and is not a gijax run folder (it holds "
                         f"{', '.join(others[:3])}{', ...' if len(others) > 3 else ''} and no "
                         f"{CONFIG_FILE}); choose a new --out")


def drop_logs_after(run_dir, step: int) -> None:
    """Remove what ``metrics.jsonl`` and the TensorBoard files hold for steps after ``step``.

    A run killed between two checkpoints has logged steps that its resumed run computes (and
    logs) again from the last checkpoint; dropping them first keeps one record per step, so
    readers need no de-duplication. A line or event cut short by the kill goes too.
    """
    from gijax.io.events import drop_events_after

    run_dir = Path(run_dir)
    path = run_dir / METRICS_FILE
    if path.exists():
        kept = []
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if isinstance(record, dict) and int(record.get("step", 0)) <= step:
                kept.append(line)
        write_text_atomic(path, "".join(line + "\n" for line in kept))
    for events in sorted((run_dir / "tb").glob("events.out.tfevents.*")):
        drop_events_after(events, step)
