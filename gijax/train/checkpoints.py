"""Checkpoints under a run folder (orbax): periodic keep-N, keep-best, resume with fallback.

``RUN/checkpoints/<step>/`` holds the periodic checkpoints (the newest ``keep``), and
``RUN/best/<step>/`` the single best by a validation metric. Each checkpoint has two items:
``state`` (the training state pytree: parameters, other model variables such as BatchNorm
statistics and RNG streams, optimiser state, step) and ``meta`` (JSON: step, preset, candidate
list, loader position, metrics). orbax writes into a temporary folder and renames it when
complete, so a process killed mid-save leaves no folder that looks complete; such leftovers
are removed when the run resumes. A checkpoint that fails to restore (truncated or corrupt
files) is moved to ``RUN/corrupt/`` with a warning and the next older one is used.
"""

from __future__ import annotations

import json
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
             best_mode: str = "min") -> ocp.CheckpointManager:
    opts = dict(max_to_keep=keep, create=True, enable_async_checkpointing=False,
                cleanup_tmp_directories=True)
    if best_metric is not None:
        opts.update(best_fn=lambda m: float(m[best_metric]), best_mode=best_mode,
                    keep_checkpoints_without_metrics=False)
    return ocp.CheckpointManager(directory.absolute(), options=ocp.CheckpointManagerOptions(**opts),
                                 item_names=("state", "meta"))


def _to_jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


class CheckpointStore:
    """The checkpoints of one run folder.

    Args:
      run_dir: the run folder.
      keep: periodic checkpoints kept (older ones are deleted after a newer one is complete).
      best_metric / best_mode: the validation metric that ranks ``best/`` ('min' or 'max');
        ``None`` disables keep-best.
    """

    def __init__(self, run_dir: str | Path, keep: int = 3, best_metric: Optional[str] = "mae",
                 best_mode: str = "min"):
        self.run_dir = Path(run_dir)
        self.periodic = _manager(self.run_dir / PERIODIC, keep)
        self.best = (_manager(self.run_dir / BEST, 1, best_metric, best_mode)
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
        out = manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        return dict(out["meta"])

    def _quarantine(self, manager: ocp.CheckpointManager, step: int, exc: BaseException) -> None:
        src = Path(manager.directory) / str(step)
        dst = self.run_dir / CORRUPT / f"{Path(manager.directory).name}-{step}"
        msg = (f"checkpoint {src} is unreadable ({type(exc).__name__}: {str(exc)[:200]}); "
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
                out = manager.restore(step, args=ocp.args.Composite(
                    state=ocp.args.StandardRestore(abstract_state)))
            except Exception as exc:                       # noqa: BLE001
                self._quarantine(manager, step, exc)
                continue
            return out["state"], meta
        raise ValueError(f"{Path(manager.directory)}: no readable checkpoint among steps {steps}; "
                         f"the unreadable ones were moved to {self.run_dir / CORRUPT}")

    def latest_step(self) -> Optional[int]:
        return self.periodic.latest_step()

    def close(self) -> None:
        self.periodic.close()
        if self.best is not None:
            self.best.close()
