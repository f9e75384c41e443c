"""core.progress: a tqdm bar on a terminal, timestamped lines at a bounded rate in a log."""

from __future__ import annotations

import io
import re

import pytest

from forcdecode.core.progress import counter, format_duration, progress, resolve_mode, say

STAMP = r"\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2}"


class Terminal(io.StringIO):
    """A stream that says it is a terminal, as stderr does in an interactive shell."""

    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(autouse=True)
def _no_forced_mode(monkeypatch):
    monkeypatch.delenv("FORCDECODE_PROGRESS", raising=False)
    monkeypatch.delenv("FORCDECODE_PROGRESS_INTERVAL_S", raising=False)


def test_log_lines_are_timestamped_and_rate_limited():
    """10 items of 10 s each, one line per 30 s: the start, after items 3, 6, 9, and the end."""
    log, clock = io.StringIO(), Clock()
    seen = []
    for item in progress(range(10), desc="screen chunk 3", unit="samples", stream=log, interval_s=30, clock=clock):
        clock.t += 10.0
        seen.append(item)
    assert seen == list(range(10))
    lines = log.getvalue().splitlines()
    assert len(lines) == 5 and "\r" not in log.getvalue()
    assert all(re.match(r"\[" + STAMP + r"\] screen chunk 3: ", line) for line in lines)
    assert lines[0].endswith("screen chunk 3: 0/10 samples (0 %)")
    assert lines[1].endswith("3/10 samples (30 %), elapsed 30 s, about 1 min 10 s left")
    assert "9/10 samples (90 %), elapsed 1 min 30 s, about 10 s left" in lines[3]
    assert lines[4].endswith("10/10 samples (100 %), elapsed 1 min 40 s, done")


def test_terminal_gets_a_tqdm_bar_and_messages_above_it():
    terminal = Terminal()
    with progress(total=4, desc="re-simulation", unit="profiles", stream=terminal) as bar:
        for k in range(4):
            bar.update()
            if k == 1:
                bar.write("profile 2 converged")
                bar.set_status("RMS 0.012")
    out = terminal.getvalue()
    assert "\r" in out and "re-simulation" in out  # redrawn in place, not one line per update
    assert "4/4" in out and "100%" in out and "profiles/s" in out and "RMS 0.012" in out
    assert re.search(r"\[" + STAMP + r"\] profile 2 converged\n", out)
    assert "elapsed" not in out and "%)" not in out  # no log lines on a terminal


def test_mode_follows_the_stream_and_the_environment(monkeypatch):
    assert resolve_mode(Terminal()) == "bar" and resolve_mode(io.StringIO()) == "log"
    monkeypatch.setenv("FORCDECODE_PROGRESS", "log")
    assert resolve_mode(Terminal()) == "log"
    monkeypatch.setenv("FORCDECODE_PROGRESS", "off")
    quiet = Terminal()
    for _ in progress(range(3), stream=quiet):
        pass
    assert quiet.getvalue() == ""
    say("messages are not progress: they stay", stream=quiet)
    assert quiet.getvalue().endswith("messages are not progress: they stay\n")
    monkeypatch.setenv("FORCDECODE_PROGRESS", "loud")
    with pytest.raises(ValueError, match="progress mode"):
        resolve_mode(io.StringIO())


def test_counter_drives_done_total_callbacks():
    log, clock = io.StringIO(), Clock()
    report = counter("family", "curves", stream=log, interval_s=0, clock=clock)
    for done in (1, 2, 3):
        clock.t += 2.0
        report(done, 3)
    report(1, 2)  # a second run of the same work starts a new count
    report(2, 2)
    lines = log.getvalue().splitlines()
    assert [line.split("family: ")[1].split(" curves")[0] for line in lines] == \
        ["0/3", "1/3", "2/3", "3/3", "0/2", "1/2", "2/2"]  # the end once, by close()
    assert lines[3].endswith("elapsed 4 s, done")  # counted from the first report and lines[-1].endswith("done")


def test_say_writes_one_timestamped_line():
    log = io.StringIO()
    say("M_s 470 kA/m: RMS 0.0213", stream=log)
    assert re.fullmatch(r"\[" + STAMP + r"\] M_s 470 kA/m: RMS 0\.0213\n", log.getvalue())
    assert format_duration(3725) == "1 h 02 min" and format_duration(59.4) == "59 s"
