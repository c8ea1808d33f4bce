"""What a benchmark ran on: machine, load, library versions and the source revision."""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Sequence

PACKAGES = ("jax", "jaxlib", "flax", "optax", "numpy", "onnx", "onnxruntime", "jax2onnx")


def cpu_model() -> str:
    """The CPU's marketing name from /proc/cpuinfo, else ``platform.processor()``."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def git_revision(root: str | os.PathLike | None = None, ignore: Sequence[str] = ()) -> dict:
    """``commit`` (hash) and ``dirty`` (uncommitted changes to tracked files) of the checkout at
    ``root`` (default: the one holding this package); ``commit`` None outside a git checkout.
    Changes under the paths in ``ignore`` (relative to ``root``; e.g. the result files a script
    rewrites itself) do not count as dirty."""
    root = Path(root) if root else Path(__file__).resolve().parents[2]
    pathspec = ["--", ".", *(f":!{p}" for p in ignore)] if ignore else []
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                                text=True, timeout=10).stdout.strip() or None
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no",
                                 *pathspec],
                                cwd=root, capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit, "dirty": bool(status.strip()) if commit else None}


def invocation(command: str) -> dict:
    """Who ran what, where and with which code: ``command``, the working directory, the code
    revision (:func:`git_revision`), package versions, host and UTC time; what a long job that
    runs in pieces records for each piece."""
    return {"command": command, "cwd": os.getcwd(), "git": git_revision(),
            "versions": versions(), "host": platform.node(),
            "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def versions() -> dict:
    out = {"python": sys.version.split()[0]}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def load_average() -> list[float] | None:
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def machine_info(device=None) -> dict:
    """Host, CPU, memory, load, the JAX device, library versions and git revision."""
    import jax
    import psutil

    dev = device if device is not None else jax.devices()[0]
    return {
        "time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "host": platform.node(),
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "memory_gib": round(psutil.virtual_memory().total / 2**30, 1),
        "load_average": load_average(),
        "backend": dev.platform,
        "device": getattr(dev, "device_kind", str(dev)),
        "versions": versions(),
        "git": git_revision(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }
