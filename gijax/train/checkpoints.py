"""Checkpoints under a run folder (orbax): periodic keep-N, keep-best, resume with fallback.

``RUN/checkpoints/<step>/`` holds the periodic checkpoints (the newest ``keep``), and
``RUN/best/<step>/`` the single best by a validation metric. Each checkpoint has two items:
``state`` (the training state pytree: parameters, other model variables such as BatchNorm
statistics and RNG streams, optimiser state, step) and ``meta`` (JSON: step, preset, candidate
list, loader position, metrics). orbax writes into a temporary folder and renames it when
complete, so a process killed mid-save leaves no folder that looks complete; such leftovers
are removed when the run resumes. A checkpoint that fails to restore (truncated or corrupt
files) is moved to ``RUN/corrupt/`` with a one-line warning and the next older one is used.
A read-only store (evaluation, inference, export) changes nothing in the run folder: it skips
unreadable checkpoints with the same warning and leaves temporary folders alone (they may
belong to a training process that is saving right now).
"""

from __future__ import annotations

import contextlib
import json
import logging
import shutil
import warnings
from pathlib import Path
from typing import Any, Optional

import jax
import orbax.checkpoint as ocp

PERIODIC = "checkpoints"
BEST = "best"
CORRUPT = "corrupt"


def _manager(directory: Path, keep: int, best_metric: str | None = None,
             best_mode: str = "min", read_only: bool = False) -> ocp.CheckpointManager:
    opts = dict(max_to_keep=keep, create=not read_only, enable_async_checkpointing=False,
                cleanup_tmp_directories=not read_only)
    if best_metric is not None:
        opts.update(best_fn=lambda m: float(m[best_metric]), best_mode=best_mode,
                    keep_checkpoints_without_metrics=False)
    return ocp.CheckpointManager(directory.absolute(), options=ocp.CheckpointManagerOptions(**opts),
                                 item_names=("state", "meta"))


@contextlib.contextmanager
def _quiet_restore():
    """Silence asyncio's logger while orbax restores: when one array of a damaged checkpoint
    fails, every other pending read is cancelled and asyncio logs each one with a full
    traceback (thousands of lines for a real model). The failure itself still raises."""
    logger = logging.getLogger("asyncio")
    previous = logger.disabled
    logger.disabled = True
    try:
        yield
    finally:
        logger.disabled = previous


def _reason(exc: BaseException) -> str:
    """The innermost cause of a restore failure, on one line (orbax wraps the real one)."""
    seen = []
    while exc is not None and exc not in seen:
        seen.append(exc)
        exc = exc.__cause__ or exc.__context__
    root = seen[-1]
    text = (str(root).strip().splitlines() or [""])[0]
    return f"{type(root).__name__}: {text[:200]}"


def _to_jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


class CheckpointStore:
    """The checkpoints of one run folder.

    Args:
      run_dir: the run folder.
      keep: periodic checkpoints kept (older ones are deleted after a newer one is complete).
      best_metric / best_mode: the validation metric that ranks ``best/`` ('min' or 'max');
        ``None`` disables keep-best.
      read_only: for readers of the run (no saving, no folder created, moved or deleted).
    """

    def __init__(self, run_dir: str | Path, keep: int = 3, best_metric: Optional[str] = "mae",
                 best_mode: str = "min", read_only: bool = False):
        self.run_dir = Path(run_dir)
        self.read_only = read_only
        self.periodic = _manager(self.run_dir / PERIODIC, keep, read_only=read_only)
        self.best = (_manager(self.run_dir / BEST, 1, best_metric, best_mode, read_only)
                     if best_metric else None)
        self.best_metric, self.best_mode = best_metric, best_mode

    # ------------------------------------------------------------------ saving
    def save(self, step: int, state: Any, meta: dict) -> None:
        """Periodic checkpoint of ``state`` at ``step`` (blocks until it is complete)."""
        args = ocp.args.Composite(state=ocp.args.StandardSave(state),
                                  meta=ocp.args.JsonSave(_to_jsonable(meta)))
        self.periodic.save(step, args=args, force=True)
        self.periodic.wait_until_finished()

    def best_value(self) -> Optional[float]:
        """The metric of the current best checkpoint (None if there is none)."""
        if self.best is None or self.best.best_step() is None:
            return None
        meta = self.read_meta(self.best, self.best.best_step())
        return meta.get("metrics", {}).get(self.best_metric)

    def maybe_save_best(self, step: int, state: Any, meta: dict, metrics: dict) -> bool:
        """Save to ``best/`` when ``metrics[best_metric]`` beats the current best."""
        if self.best is None:
            return False
        value = float(metrics[self.best_metric])
        current = self.best_value()
        better = current is None or (value < current if self.best_mode == "min" else value > current)
        if not better:
            return False
        meta = dict(meta, metrics={k: float(v) for k, v in metrics.items()})
        args = ocp.args.Composite(state=ocp.args.StandardSave(state),
                                  meta=ocp.args.JsonSave(_to_jsonable(meta)))
        self.best.save(step, args=args, metrics={self.best_metric: value}, force=True)
        self.best.wait_until_finished()
        return True

    # ------------------------------------------------------------------ loading
    @staticmethod
    def read_meta(manager: ocp.CheckpointManager, step: int) -> dict:
        with _quiet_restore():
            out = manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        return dict(out["meta"])

    def _quarantine(self, manager: ocp.CheckpointManager, step: int, exc: BaseException) -> None:
        src = Path(manager.directory) / str(step)
        dst = self.run_dir / CORRUPT / f"{Path(manager.directory).name}-{step}"
        if self.read_only:
            warnings.warn(f"checkpoint {src} is unreadable ({_reason(exc)}); skipping it and "
                          f"falling back to the previous checkpoint", RuntimeWarning, stacklevel=3)
            return
        msg = (f"checkpoint {src} is unreadable ({_reason(exc)}); "
               f"moved to {dst} and falling back to the previous checkpoint")
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
        if jax.process_index() == 0 and src.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            if dst.exists():
                shutil.rmtree(dst)
            shutil.move(str(src), str(dst))
        manager.reload()

    def restore_latest(self, abstract_state: Any, check_meta=None, which: str = PERIODIC):
        """Newest readable checkpoint -> (state, meta), or None when there is none at all.

        ``abstract_state`` is a pytree of ``jax.ShapeDtypeStruct`` (with shardings) that fixes
        the structure, dtypes and placement of the restored arrays. ``check_meta(meta)`` may
        raise ValueError for a checkpoint that belongs to another configuration (that error is
        not treated as corruption). Raises ValueError when checkpoints exist but none is
        readable.
        """
        manager = self.periodic if which == PERIODIC else self.best
        steps = sorted(manager.all_steps(), reverse=True)
        if not steps:
            return None
        for step in steps:
            try:
                meta = self.read_meta(manager, step)
            except Exception as exc:                       # noqa: BLE001 - any read failure
                self._quarantine(manager, step, exc)
                continue
            if check_meta is not None:
                check_meta(meta)
            try:
                with _quiet_restore():
                    out = manager.restore(step, args=ocp.args.Composite(
                        state=ocp.args.StandardRestore(abstract_state)))
            except Exception as exc:                       # noqa: BLE001
                self._quarantine(manager, step, exc)
                continue
            return out["state"], meta
        where = ("" if self.read_only else
                 f"; the unreadable ones were moved to {self.run_dir / CORRUPT}")
        raise ValueError(f"{Path(manager.directory)}: no readable checkpoint among steps "
                         f"{steps}{where}")

    def latest_step(self) -> Optional[int]:
        return self.periodic.latest_step()

    def close(self) -> None:
        self.periodic.close()
        if self.best is not None:
            self.best.close()
