"""The training loop: data-parallel steps, validation, checkpoints and resume.

:class:`Trainer` builds (or restores) the state of one run folder and :meth:`Trainer.fit` is the
loop, read top to bottom: get a batch, take a step, log, save, validate. The numerical work is
the jitted step of :mod:`gijax.train.step`; what a run folder may be and what it resumes from is
:mod:`gijax.train.run_folder`; the records (``metrics.jsonl``, TensorBoard, sample images,
progress) are :mod:`gijax.train.logbook`. Only process 0 writes logs, sample images and the run
config; every process takes part in the (collective) checkpoint saves. Validation runs on each
process's first local device over the whole validation set (every process computes the same
numbers, so no communication is needed to rank checkpoints).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gijax.candidates.parametrisation import logits_from_candidates
from gijax.evaluate.loop import evaluate_predictions
from gijax.evaluate.prediction import Prediction
from gijax.geometry.rig import Rig
from gijax.io.lock import FolderLock
from gijax.io.paths import write_text_atomic
from gijax.model import model_rig
from gijax.random_streams import device_key
from gijax.store.checkpoints import CheckpointStore
from gijax.store.configs import model_config_to_dict
from gijax.train import run_folder as R
from gijax.train import step as S
from gijax.train.config import TrainConfig, save_run_config
from gijax.train.logbook import METRICS_FILE, Logbook
from gijax.train.sources import RIG_KEY


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


class Trainer:
    """Trains one run folder; resumes from its newest readable checkpoint when there is one.

    Args:
      config: the training configuration.
      run_dir: the run folder (created if needed).
      rig: the training rig (sweep geometry), or a sequence of rigs, one per training
        dataset: batches then carry ``rig_index`` (:class:`gijax.train.sources.MixedStream`).
      make_train_stream: ``make(state | None) -> stream`` (see :mod:`gijax.train.sources`).
      make_val_batches: ``() -> iterable of batches`` (whole validation set), or None.
      rig_name: recorded in the run config.
      progress: show a tqdm progress bar.
      devices: devices of the data-parallel mesh (default: all devices of all processes).
      val_rig: the validation data's rig (default: the training rig).
      invocation: what started this piece of the run, logged with its start or resume event.
      candidates: the run's candidate list (metres), resolved once by
        :func:`gijax.train.run_folder.run_candidates`; by default resolved here the same way
        (with the first rig).
    """

    def __init__(self, config: TrainConfig, run_dir, rig: Rig | Sequence[Rig],
                 make_train_stream: Callable,
                 make_val_batches: Optional[Callable[[], Iterable[dict]]] = None,
                 rig_name: str = "", progress: bool = True, devices=None,
                 val_rig: Optional[Rig] = None, invocation: Optional[dict] = None,
                 candidates=None):
        from gijax.model import create_model

        self.config = config
        # What started this piece of the run (command, code revision, ...): logged with the
        # start or resume event, so a training split over several runs says how each went.
        self.invocation = dict(invocation or {})
        self.mc = config.model_config()
        self.run_dir = Path(run_dir)
        rigs = list(rig) if isinstance(rig, (list, tuple)) else [rig]
        self.rigs = [model_rig(r) for r in rigs]
        self.rig = self.rigs[0]
        self.val_rig = self.rig if val_rig is None else model_rig(val_rig)
        self.make_train_stream = make_train_stream
        self.make_val_batches = make_val_batches
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
        if candidates is None:
            candidates = R.run_candidates(config, self.run_dir, rigs[0])
        self.candidates = np.asarray(candidates, np.float64)
        R.check_run_folder(self.run_dir)
        fresh = not self.run_dir.exists()
        self.run_dir.mkdir(parents=True, exist_ok=True)
        # One writer per run folder; process 0 holds the lock for the processes of its run.
        self._lock = FolderLock(self.run_dir, "run folder") if self.is_main else None
        if self._lock is not None:
            self._lock.acquire()
        try:
            if R.is_resume(self.run_dir):
                R.check_resumable(self.run_dir, config, self.mc)
            if self.is_main:
                save_run_config(self.run_dir, config, self.candidates, rig_name)
            self.log = Logbook(self.run_dir, self.is_main, progress)

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
            # The checkpoint store's creation is the first collective (orbax syncs the
            # processes through gloo).
            S.meet_all_processes("checkpoint-store")
            self.store = CheckpointStore(self.run_dir, config.keep,
                                         config.best_metric if config.keep_best else None,
                                         config.best_mode)
            self._restore(state, params, rest, logits0)
            # Frozen BatchNorm: the step runs the network as at inference (running statistics
            # used, not updated); the state keeps the same variables either way.
            step_def = self.eval_def if config.batch_norm == "frozen" else self.train_def
            self._step = S.jit_train_step(
                S.build_train_step(step_def, self.tx, self.mc.loss, config.grad_accum,
                                   config.bf16, self.tx_cand, self.d_range,
                                   config.objective()), self.mesh)
            self._eval = jax.jit(S.build_eval_forward(self.eval_def))
            self._cand = jnp.asarray(self.candidates, jnp.float32)
            if config.learn_candidates:
                self._sync_candidates()
            self._stream = None
            self._perturb = None
        except BaseException:
            if self._lock is not None:
                self._lock.release()
            if fresh and self.is_main:       # nothing was trained: leave no folder behind
                shutil.rmtree(self.run_dir, ignore_errors=True)
            raise

    @property
    def history(self) -> list[dict]:
        """Every record this trainer logged (training and validation)."""
        return self.log.history

    # ----------------------------------------------------------------- loop
    def fit(self, steps: Optional[int] = None) -> list[dict]:
        """Train until ``steps`` (default ``config.steps``) optimiser updates are done."""
        cfg = self.config
        total = cfg.steps if steps is None else int(steps)
        if self._stream is None:
            self._stream = self.make_train_stream(self.stream_state)
        stream = self._stream
        step = self.start_step
        self.log.open(step, total, self.invocation)
        if self._unsaved_pack_step is not None:
            # Restored from a pack into a folder without that step: checkpoint it first, so
            # the folder holds weights even when no step is left to train (a finished pack
            # restored on a new machine).
            if cfg.learn_candidates:
                self._sync_candidates()
            self.store.save(step, self.state, self._meta(step, self.stream_state))
            self._unsaved_pack_step = None
        n_last = 0
        # The loss of a step is read once the next step is dispatched, so that the device
        # computes while the host places the next batch; it is read at once before a
        # checkpoint or a validation (a non-finite loss is never saved) and at the end.
        pending = None
        try:
            while step < total:
                t_wait = time.perf_counter()
                local = next(stream)
                self.log.waited(time.perf_counter() - t_wait)
                rig = self.rigs[local.get(RIG_KEY, 0)]
                if cfg.calibration_error_deg:
                    rig = self.calibrated_rig(rig, step)
                self.state, out = self._step(self.state, S.place_batch(local, self.mesh),
                                             rig, self._cand)
                step += 1
                n_last += cfg.batch_size
                if pending is not None:
                    self._log_loss(*pending)
                    pending = None
                if step % cfg.log_every == 0 or step == total:
                    pending, n_last = (step, out, n_last), 0
                self.log.advance()

                last = step == total
                saving = (cfg.ckpt_every and step % cfg.ckpt_every == 0) or last
                validating = ((cfg.val_every and step % cfg.val_every == 0)
                              or (last and self.make_val_batches))
                if pending is not None and (saving or validating):
                    self._log_loss(*pending)
                    pending = None
                if cfg.learn_candidates and (saving or validating):
                    self._sync_candidates()
                    self.log.learned_candidates(step, self.current_candidates, self.candidates)
                if saving:
                    self.store.save(step, self.state, self._meta(step, stream.state()))
                if validating:
                    metrics = self.validate(step)
                    if metrics is not None:
                        record = {"step": step, "split": "val", **metrics}
                        if cfg.learn_candidates:   # logged beside the numbers, not ranked
                            record["candidates"] = self.current_candidates.tolist()
                        self.log.log(record)
                        if cfg.keep_best:
                            self.store.maybe_save_best(step, self.state,
                                                       self._meta(step, stream.state()), metrics)
                if saving:     # after the validation, so the pack's log holds it
                    self._write_pack(step, stream.state())
        finally:
            self.log.close()
        self.start_step = step
        return self.history

    def _log_loss(self, step: int, out: dict, samples: int) -> None:
        self.log.loss(step, out, samples, float(self.lr_fn(step - 1)))

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
        self.log.samples(step, [(p.inv_distance, d) for p, d in result.examples],
                         self.candidates)
        return result.metrics["gijax"]

    # ----------------------------------------------------------------- state and checkpoints
    def _restore(self, state, params, rest, logits0) -> None:
        """``self.state``, ``start_step`` and ``stream_state``: from the resume pack when it is
        ahead of the newest checkpoint, else that checkpoint, else a fresh start (from
        ``config.init_from`` when given)."""
        abstract = S.abstract_like(state, S.replicated(self.mesh))
        self._unsaved_pack_step = None
        check = lambda meta: R.check_checkpoint_meta(  # noqa: E731
            meta, self.run_dir, self.config, self.mc)
        restored = self.store.restore_latest(abstract, check)
        pack = R.newer_pack(self.run_dir, self.config, self.mc, self.candidates,
                            None if restored is None else int(restored[1]["step"]))
        if pack is not None:
            from gijax.store.packs import restore_state

            self.state = S.place_state(restore_state(pack, abstract), self.mesh)
            self.start_step, self.stream_state = pack.step, pack.meta.get("stream")
            self._unsaved_pack_step = pack.step
            if self.is_main:
                write_text_atomic(self.run_dir / METRICS_FILE, "".join(pack.metrics))
        elif restored is None:
            if self.config.init_from:
                params, rest = R.initial_variables(self.config, self.mc, params, rest)
                state = S.init_state(params, rest, self.tx, logits0, self.tx_cand)
            self.state = S.place_state(state, self.mesh)
            self.start_step, self.stream_state = 0, None
        else:
            self.state, meta = restored
            self.start_step, self.stream_state = int(meta["step"]), meta.get("stream")

    def _meta(self, step: int, stream_state) -> dict:
        meta = {"step": step, "preset": self.config.preset,
                "candidates": [float(c) for c in self.candidates], "stream": stream_state,
                "time": time.time()}
        if self.config.learn_candidates:
            meta["learned_candidates"] = self.current_candidates.tolist()
        return meta

    def _write_pack(self, step: int, stream_state) -> None:
        """Rewrite the resume pack (process 0) with the state, the stream and the log."""
        if not (self.config.pack and self.is_main):
            return
        from gijax.store.packs import write_pack

        meta = {**self._meta(step, stream_state), "train_config": self.config.to_dict(),
                "model_config": model_config_to_dict(self.mc),
                "command": self.invocation.get("command"), "git": self.invocation.get("git")}
        write_pack(self.config.pack, self.state, meta, self.log.lines())

    def _sync_candidates(self) -> None:
        """With a learned list: the current list from the state, as numpy and on device."""
        logits = np.asarray(self.state["cand_logits"].addressable_data(0))
        self._cand = S.state_candidates({"cand_logits": jnp.asarray(logits)}, self.d_range)
        self.current_candidates = np.asarray(self._cand, np.float64)

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
        key = device_key(self.config.seed, "calibration", step)
        return self._perturb(key, rig)

    def close(self) -> None:
        if self._stream is not None:
            getattr(self._stream, "close", lambda: None)()
            self._stream = None
        self.store.close()
        if self._lock is not None:
            self._lock.release()
