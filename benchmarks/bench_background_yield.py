"""Does a background job yield the CPU to the foreground? Foreground speed beside CPU burners
started four ways.

Linux groups the processes of each session into an *autogroup*, and the scheduler first shares
the CPU equally between autogroups, then by ``nice`` within each. A background job started in
its own session (``setsid``, as a job that outlives its terminal is) with ``nice -n 19``
therefore still takes half the CPU from the foreground's session; lowering its autogroup's
priority (``echo 19 > /proc/self/autogroup``) is what makes it yield. This measures that: a
fixed foreground workload (float32 matmuls on every core, through numpy's BLAS) timed alone and
beside one busy process per core, started

* ``same session, nice 0``: an ordinary competitor;
* ``same session, nice 19``: ``nice`` within the foreground's autogroup;
* ``own session, nice 19``: ``setsid nice -n 19``, a new autogroup at its default priority;
* ``own session, autogroup 19``: ``setsid bash -c 'echo 19 > /proc/self/autogroup; exec ...'``,
  the way docs/training.md starts long trainings.

    python benchmarks/bench_background_yield.py            # about a minute
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BURN = "import time\nwhile True:\n    sum(i * i for i in range(10000))\n"
MODES = ("alone", "same session, nice 0", "same session, nice 19", "own session, nice 19",
         "own session, autogroup 19")


def calibrate_reps(seconds_hint: float, n: int = 768) -> int:
    """How many n x n float32 matmuls take about ``seconds_hint`` on this machine, alone."""
    import numpy as np

    a = np.random.default_rng(0).standard_normal((n, n)).astype(np.float32)
    t0 = time.perf_counter()
    reps = 0
    while time.perf_counter() - t0 < 0.5:
        a @ a
        reps += 1
    per = (time.perf_counter() - t0) / reps
    return max(int(seconds_hint / per), 1)


def timed(reps: int, n: int = 768) -> float:
    """Seconds for ``reps`` n x n float32 matmuls."""
    import numpy as np

    a = np.random.default_rng(0).standard_normal((n, n)).astype(np.float32)
    t0 = time.perf_counter()
    for _ in range(reps):
        a @ a
    return time.perf_counter() - t0


def start_burners(mode: str, count: int) -> list:
    py = [sys.executable, "-c", BURN]
    procs = []
    for _ in range(count):
        if mode == "same session, nice 0":
            p = subprocess.Popen(py)
        elif mode == "same session, nice 19":
            p = subprocess.Popen(py, preexec_fn=lambda: os.nice(19))
        elif mode == "own session, nice 19":
            p = subprocess.Popen(["nice", "-n", "19", *py], start_new_session=True)
        elif mode == "own session, autogroup 19":
            cmd = "echo 19 > /proc/self/autogroup; exec " + shlex.join(py)
            p = subprocess.Popen(["bash", "-c", cmd], start_new_session=True)
        else:
            raise ValueError(mode)
        procs.append(p)
    time.sleep(1.0)               # let them reach their loops
    return procs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=6.0,
                    help="length of the foreground workload when it runs alone")
    ap.add_argument("--burners", type=int, default=os.cpu_count(),
                    help="busy background processes (default: one per core)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "background_yield.json"),
                    help="where the JSON results are written")
    args = ap.parse_args()
    if not Path("/proc/self/autogroup").exists():
        print("this kernel has no autogroups (/proc/self/autogroup); nothing to measure")
        return 0
    reps = calibrate_reps(args.seconds)
    rows = []
    for mode in MODES:
        procs = [] if mode == "alone" else start_burners(mode, args.burners)
        try:
            seconds = timed(reps)
        finally:
            for p in procs:
                p.kill()
            for p in procs:
                p.wait()
        rows.append({"background": mode, "foreground_s": seconds})
    alone = rows[0]["foreground_s"]
    for r in rows:
        r["slowdown"] = r["foreground_s"] / alone
    print(f"foreground: {reps} float32 768 x 768 matmuls; background: {args.burners} busy "
          f"process(es); {os.cpu_count()} CPU(s)")
    print(f"{'background':28s} {'foreground s':>13s} {'slowdown':>9s}")
    for r in rows:
        print(f"{r['background']:28s} {r['foreground_s']:13.2f} {r['slowdown']:8.2f}x")
    from gijax.io.paths import write_json_atomic

    out = write_json_atomic(args.out, {"reps": reps, "burners": args.burners,
                                       "cpus": os.cpu_count(), "rows": rows}, indent=1)
    print(f"written {out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
