"""The elapsed-time line of long calls that count no steps (gijax.cli.waiting)."""

import io
import time

from gijax.cli.waiting import working


def test_working_ticks_while_the_block_runs_and_says_when_it_ended():
    out = io.StringIO()
    with working("RS-E32 sphere sweep", stream=out, always=True):
        time.sleep(1.3)
    text = out.getvalue()
    ticks = [t for t in text.split("\r") if t.endswith("elapsed")]
    assert len(ticks) >= 2 and ticks[0] == "RS-E32 sphere sweep: 00:00 elapsed"
    assert text.endswith("\rRS-E32 sphere sweep: done in 00:01\n")


def test_working_draws_nothing_when_off_or_not_on_a_terminal():
    for kwargs in ({"enabled": False, "always": True}, {}):
        out = io.StringIO()                       # StringIO is not a terminal
        with working("x", stream=out, **kwargs):
            time.sleep(0.6)
        assert out.getvalue() == ""


def test_working_ends_its_line_when_the_block_raises():
    out = io.StringIO()
    try:
        with working("x", stream=out, always=True):
            raise KeyError("stop")
    except KeyError:
        pass
    assert out.getvalue() == "\rx: stopped after 00:00\n"
