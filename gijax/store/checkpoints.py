"""Orbax checkpoint folders of a run: their layout, saving them (keep-N, keep-best), and
restoring the newest readable one.

``RUN/checkpoints/<step>/`` holds the newest ``keep`` periodic checkpoints and
``RUN/best/<step>/`` the single best by a validation metric. Each checkpoint has two items:
``state`` (a pytree: the training state: parameters, other model variables such as BatchNorm
statistics and RNG streams, optimiser state, step) and ``meta`` (JSON: step, preset, candidate
list, loader position, metrics). orbax writes into a temporary folder and renames it when
complete, so a folder that looks complete is one, and a process killed mid-save leaves
leftovers that are removed when the run resumes.

Two kinds of user: the trainer (:class:`CheckpointStore`), which saves, and on resume moves a
checkpoint that fails to restore (truncated or corrupt files) to ``RUN/corrupt/`` with a
one-line warning and uses the next older one; and every reader (evaluation, inference, export,
:func:`restore_newest` with :func:`open_manager` ``read_only``), which changes nothing: it
skips an unreadable checkpoint with a one-line warning and leaves temporary folders alone,
since they may belong to a training process that is saving right now.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import shutil
import signal
import threading
import warnings
from pathlib import Path
from typing import Any, Callable, Optional

import jax
import orbax.checkpoint as ocp

PERIODIC = "checkpoints"
BEST = "best"
CORRUPT = "corrupt"
STATE, META = "state", "meta"


class ConfigurationMismatch(ValueError):
    """A readable checkpoint that belongs to another configuration than the one restoring it
    (another preset, candidate count or parameter shapes): an error, not damage to skip."""


def open_manager(directory: Path, keep: int = 1, best_metric: str | None = None,
                 best_mode: str = "min", read_only: bool = False) -> ocp.CheckpointManager:
    """The orbax manager of one checkpoint folder (``RUN/checkpoints`` or ``RUN/best``).

    ``keep`` checkpoints are kept when saving; ``best_metric`` ranks them (``best_mode`` 'min'
    or 'max'). A ``read_only`` manager creates, cleans and deletes nothing.
    """
    opts = dict(max_to_keep=keep, create=not read_only, enable_async_checkpointing=False,
                cleanup_tmp_directories=not read_only)
    if best_metric is not None:
        opts.update(best_fn=lambda m: float(m[best_metric]), best_mode=best_mode,
                    keep_checkpoints_without_metrics=False)
    # Handlers named up front let the metadata of a step be read without restoring it.
    handlers = {STATE: ocp.StandardCheckpointHandler(), META: ocp.JsonCheckpointHandler()}
    return ocp.CheckpointManager(Path(directory).absolute(),
                                 options=ocp.CheckpointManagerOptions(**opts),
                                 item_handlers=handlers)


def _keyboard_interrupt(signum, frame):
    raise KeyboardInterrupt


@contextlib.contextmanager
def plain_sigint():
    """Keep asyncio from swapping the SIGINT handler around each orbax call.

    orbax runs its reads and writes through ``asyncio.run``, which on the main thread installs
    its own SIGINT handler and restores Python's afterwards; the ``signal`` module formats the
    repr of the handler it replaces, a task that holds the arrays in flight, which costs about
    0.3 s per restore of a small model. asyncio leaves SIGINT alone when the handler is not
    Python's default, so this installs one that does what the default does (raise
    KeyboardInterrupt) for the duration.
    """
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    previous = signal.signal(signal.SIGINT, _keyboard_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _silenced(name: str):
    """The logger ``name`` disabled for the duration (its records dropped)."""
    logger = logging.getLogger(name)
    previous = logger.disabled
    logger.disabled = True
    try:
        yield
    finally:
        logger.disabled = previous


@contextlib.contextmanager
def quiet_restore():
    """Silence asyncio's logger while orbax restores: when one array of a damaged checkpoint
    fails, every other pending read is cancelled and asyncio logs each one with a full
    traceback (thousands of lines for a real model). The failure itself still raises. SIGINT
    as in :func:`plain_sigint`."""
    with _silenced("asyncio"), plain_sigint():
        yield


class DiskFullError(OSError):
    """A checkpoint could not be written for want of disk space; its partial files are gone."""


def _disk_full(exc: BaseException) -> bool:
    seen = []
    while exc is not None and exc not in seen:
        seen.append(exc)
        if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
            return True
        if "No space left on device" in str(exc) or "os_error_code='28'" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


@contextlib.contextmanager
def writing(manager: ocp.CheckpointManager, step: int, kept: Callable[[], Optional[int]]):
    """Around one checkpoint write: SIGINT as in :func:`plain_sigint`, and a full disk turned
    into one :class:`DiskFullError` saying what the run keeps, with the partial checkpoint
    removed (it would hold the space that a resume needs).

    orbax's writer threads log each failed array, with a traceback, through absl before the
    failure reaches the caller (about a hundred lines for a small model); those records are
    dropped here, since the failure itself is raised. ``kept()`` gives the newest complete
    checkpoint's step, or None.
    """
    try:
        with _silenced("absl"), plain_sigint():
            yield
    except Exception as exc:
        if not _disk_full(exc):
            raise
        folder = Path(manager.directory)
        for partial in folder.glob(f"{step}.orbax-checkpoint-tmp*"):
            shutil.rmtree(partial, ignore_errors=True)
        last = kept()
        keeps = (f"the run keeps its checkpoint of step {last}" if last is not None
                 else "the run has no complete checkpoint yet")
        raise DiskFullError(errno.ENOSPC, f"disk full while writing the checkpoint of step "
                                          f"{step} into {folder} (its partial files are "
                                          f"removed); {keeps}: free space and run the same "
                                          f"command to continue") from None


def failure_reason(exc: BaseException) -> str:
    """The innermost cause of a restore failure, on one line (orbax wraps the real one)."""
    seen = []
    while exc is not None and exc not in seen:
        seen.append(exc)
        exc = exc.__cause__ or exc.__context__
    root = seen[-1]
    text = (str(root).strip().splitlines() or [""])[0]
    return f"{type(root).__name__}: {text[:200]}"


def step_dir(manager: ocp.CheckpointManager, step: int) -> Path:
    return Path(manager.directory) / str(step)


def read_meta(manager: ocp.CheckpointManager, step: int) -> dict:
    """The ``meta`` item of ``step``."""
    with quiet_restore():
        out = manager.restore(step, args=ocp.args.Composite(**{META: ocp.args.JsonRestore()}))
    return dict(out[META])


def state_metadata(manager: ocp.CheckpointManager, step: int):
    """The stored structure of ``step``'s ``state`` item: a pytree of orbax array metadata
    (shape, dtype, name), read without loading any array."""
    with plain_sigint():
        tree = manager.item_metadata(step)[STATE]
    return getattr(tree, "tree", tree)


def skip_unreadable(manager: ocp.CheckpointManager, step: int, exc: BaseException) -> None:
    """What a reader does with an unreadable checkpoint: warn and go on to the next older one."""
    warnings.warn(f"checkpoint {step_dir(manager, step)} is unreadable ({failure_reason(exc)}); "
                  f"skipping it and falling back to the previous checkpoint", RuntimeWarning,
                  stacklevel=3)


def restore_newest(manager: ocp.CheckpointManager, abstract_for: Callable[[int], Any],
                   check: Optional[Callable[[int, dict], None]] = None,
                   unreadable: Callable = skip_unreadable,
                   note: str = "") -> Optional[tuple[Any, dict]]:
    """The newest readable checkpoint of ``manager`` -> ``(state, meta)``; None when there is
    none at all.

    ``abstract_for(step)`` gives the pytree of ``jax.ShapeDtypeStruct`` (with shardings) that
    fixes the structure, dtypes and placement of the restored state. ``check(step, meta)`` may
    raise ValueError, and ``abstract_for`` :class:`ConfigurationMismatch`, for a checkpoint that
    belongs to another configuration: that is the caller's error, not damage, so it propagates.
    A checkpoint whose meta, structure or arrays cannot be read is passed to
    ``unreadable(manager, step, exc)`` and the next older one is tried. ValueError (ending with
    ``note``) when checkpoints exist but none is readable.
    """
    steps = sorted(manager.all_steps(), reverse=True)
    if not steps:
        return None
    for step in steps:
        try:
            meta = read_meta(manager, step)
        except Exception as exc:                       # noqa: BLE001 - any read failure
            unreadable(manager, step, exc)
            continue
        if check is not None:
            check(step, meta)
        try:
            abstract = abstract_for(step)
            with quiet_restore():
                out = manager.restore(step, args=ocp.args.Composite(
                    **{STATE: ocp.args.StandardRestore(abstract)}))
        except ConfigurationMismatch:
            raise
        except Exception as exc:                       # noqa: BLE001
            unreadable(manager, step, exc)
            continue
        return out[STATE], meta
    raise ValueError(f"{Path(manager.directory)}: no readable checkpoint among steps "
                     f"{steps}{note}")


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
        self.periodic = open_manager(self.run_dir / PERIODIC, keep)
        self.best = (open_manager(self.run_dir / BEST, 1, best_metric, best_mode)
                     if best_metric else None)
        self.best_metric, self.best_mode = best_metric, best_mode

    # ------------------------------------------------------------------ saving
    def save(self, step: int, state: Any, meta: dict) -> None:
        """Periodic checkpoint of ``state`` at ``step`` (blocks until it is complete)."""
        with writing(self.periodic, step, self.latest_step):
            self.periodic.save(step, args=self._args(state, meta), force=True)
            self.periodic.wait_until_finished()

    @staticmethod
    def _args(state: Any, meta: dict) -> ocp.args.Composite:
        return ocp.args.Composite(**{STATE: ocp.args.StandardSave(state),
                                     META: ocp.args.JsonSave(_to_jsonable(meta))})

    def best_value(self) -> Optional[float]:
        """The metric of the current best checkpoint (None if there is none)."""
        if self.best is None or self.best.best_step() is None:
            return None
        meta = read_meta(self.best, self.best.best_step())
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
        with writing(self.best, step, self.latest_step):
            self.best.save(step, args=self._args(state, meta), metrics={self.best_metric: value},
                           force=True)
            self.best.wait_until_finished()
        return True

    # ------------------------------------------------------------------ resuming
    def _quarantine(self, manager: ocp.CheckpointManager, step: int, exc: BaseException) -> None:
        src = step_dir(manager, step)
        dst = self.run_dir / CORRUPT / f"{Path(manager.directory).name}-{step}"
        warnings.warn(f"checkpoint {src} is unreadable ({failure_reason(exc)}); moved to "
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
        return restore_newest(
            self.periodic, lambda _step: abstract_state, check, self._quarantine,
            note=f"; the unreadable ones were moved to {self.run_dir / CORRUPT}")

    def latest_step(self) -> Optional[int]:
        return self.periodic.latest_step()

    def close(self) -> None:
        self.periodic.close()
        if self.best is not None:
            self.best.close()
