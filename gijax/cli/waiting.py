"""A live line for one long call that reports no steps of its own (a compiled function's first
call: XLA compiles, then runs, with nothing to count in between).

``with working("RS-E32 sphere sweep"):`` draws ``RS-E32 sphere sweep: 00:12 elapsed`` on stderr,
refreshed twice a second by a daemon thread while the block runs (compiled JAX code releases
the interpreter lock, so the thread keeps ticking), and leaves ``... done in 00:41`` when the
block ends (``stopped after`` when it raised). Off (``enabled=False``, or stderr is not a terminal and ``always=False``) it draws
nothing, so logs and tests stay clean.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time

REFRESH_S = 0.5


def _clock(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes:02d}:{secs:02d}"


@contextlib.contextmanager
def working(label: str, enabled: bool = True, stream=None, always: bool = False):
    """Show ``label`` with the elapsed time while the block runs (see the module docstring)."""
    stream = sys.stderr if stream is None else stream
    live = enabled and (always or getattr(stream, "isatty", lambda: False)())
    if not live:
        yield
        return
    start = time.perf_counter()
    stop = threading.Event()

    def tick():
        while not stop.wait(REFRESH_S):
            stream.write(f"\r{label}: {_clock(time.perf_counter() - start)} elapsed")
            stream.flush()

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    ended = "stopped after"
    try:
        yield
        ended = "done in"
    finally:
        stop.set()
        thread.join()
        stream.write(f"\r{label}: {ended} {_clock(time.perf_counter() - start)}\n")
        stream.flush()
