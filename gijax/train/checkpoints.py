"""Checkpoints of a training run: periodic keep-N, keep-best, resume with fallback.

The folder layout and the restore loop are :mod:`gijax.store.checkpoints` (shared with every
reader of a run folder). ``RUN/checkpoints/<step>/`` holds the newest ``keep`` periodic
checkpoints and ``RUN/best/<step>/`` the single best by a validation metric; each holds the
training state pytree (parameters, other model variables such as BatchNorm statistics and RNG
streams, optimiser state, step) and its meta (step, preset, candidate list, loader position,
metrics). A process killed mid-save leaves no folder that looks complete, and such leftovers are
removed when the run resumes. On resume, a checkpoint that fails to restore (truncated or
corrupt files) is moved to ``RUN/corrupt/`` with a one-line warning and the next older one is
used.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path
from typing import Any, Optional

import jax
import orbax.checkpoint as ocp

from gijax.store import checkpoints as ckpt
from gijax.store.checkpoints import BEST, CORRUPT, PERIODIC


def _to_jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


class CheckpointStore:
    """The checkpoints of the run folder a trainer writes.

    Args:
      run_dir: the run folder.
      keep: periodic checkpoints kept (older ones are deleted after a newer one is complete).
      best_metric / best_mode: the validation metric that ranks ``best/`` ('min' or 'max');
        ``None`` disables keep-best.
    """

    def __init__(self, run_dir: str | Path, keep: int = 3, best_metric: Optional[str] = "mae",
                 best_mode: str = "min"):
        self.run_dir = Path(run_dir)
        self.periodic = ckpt.open_manager(self.run_dir / PERIODIC, keep)
        self.best = (ckpt.open_manager(self.run_dir / BEST, 1, best_metric, best_mode)
                     if best_metric else None)
        self.best_metric, self.best_mode = best_metric, best_mode

    # ------------------------------------------------------------------ saving
    def save(self, step: int, state: Any, meta: dict) -> None:
        """Periodic checkpoint of ``state`` at ``step`` (blocks until it is complete)."""
        with ckpt.plain_sigint():
            self.periodic.save(step, args=self._args(state, meta), force=True)
            self.periodic.wait_until_finished()

    @staticmethod
    def _args(state: Any, meta: dict) -> ocp.args.Composite:
        return ocp.args.Composite(**{ckpt.STATE: ocp.args.StandardSave(state),
                                     ckpt.META: ocp.args.JsonSave(_to_jsonable(meta))})

    def best_value(self) -> Optional[float]:
        """The metric of the current best checkpoint (None if there is none)."""
        if self.best is None or self.best.best_step() is None:
            return None
        meta = ckpt.read_meta(self.best, self.best.best_step())
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
        with ckpt.plain_sigint():
            self.best.save(step, args=self._args(state, meta), metrics={self.best_metric: value},
                           force=True)
            self.best.wait_until_finished()
        return True

    # ------------------------------------------------------------------ resuming
    def _quarantine(self, manager: ocp.CheckpointManager, step: int, exc: BaseException) -> None:
        src = ckpt.step_dir(manager, step)
        dst = self.run_dir / CORRUPT / f"{Path(manager.directory).name}-{step}"
        warnings.warn(f"checkpoint {src} is unreadable ({ckpt.failure_reason(exc)}); moved to "
                      f"{dst} and falling back to the previous checkpoint", RuntimeWarning,
                      stacklevel=4)
        if jax.process_index() == 0 and src.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            if dst.exists():
                shutil.rmtree(dst)
            shutil.move(str(src), str(dst))
        manager.reload()

    def restore_latest(self, abstract_state: Any, check_meta=None):
        """Newest readable periodic checkpoint -> (state, meta), or None when there is none.

        ``abstract_state`` is a pytree of ``jax.ShapeDtypeStruct`` (with shardings) that fixes
        the structure, dtypes and placement of the restored arrays. ``check_meta(meta)`` may
        raise ValueError for a checkpoint that belongs to another configuration (not treated
        as corruption). Unreadable checkpoints are moved to ``RUN/corrupt/``; ValueError when
        checkpoints exist but none is readable.
        """
        check = None if check_meta is None else (lambda _step, meta: check_meta(meta))
        return ckpt.restore_newest(
            self.periodic, lambda _step: abstract_state, check, self._quarantine,
            note=f"; the unreadable ones were moved to {self.run_dir / CORRUPT}")

    def latest_step(self) -> Optional[int]:
        return self.periodic.latest_step()

    def close(self) -> None:
        self.periodic.close()
        if self.best is not None:
            self.best.close()
