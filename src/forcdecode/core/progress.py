"""Progress of long commands that a person can follow: a tqdm bar when stderr is a terminal, plain
timestamped lines when it goes to a log (Snakemake's ``log:`` files, ``> run.log 2>&1``).

    for sample in progress(samples, desc="screen chunk 3", unit="samples"):
        ...
    with progress(total=n, desc="re-simulation", unit="profiles") as bar:
        bar.update(); bar.write("profile 1 done")      # a message that does not break the bar
    resimulate(..., progress=counter("re-simulation", "profiles"))   # (done, total) callbacks
    say("M_s 470 kA/m: RMS 0.02")                        # a timestamped line, bar-safe
    echo("result row")                                   # a plain line on stdout, bar-safe

In a log, a line is written when the work starts, at most every ``interval_s`` seconds while it
runs (default 30 s) and when it ends: ``[2026-05-01 12:00:30] screen chunk 3: 5/20 samples (25 %),
elapsed 1 min 02 s, about 3 min 06 s left``. ``FORCDECODE_PROGRESS`` = ``bar``, ``log`` or ``off``
forces a mode (default ``auto``); ``FORCDECODE_PROGRESS_INTERVAL_S`` sets the log interval.
"""

from __future__ import annotations

import io
import os
import sys
import time
from datetime import datetime
from typing import Callable, Iterable, TextIO

from tqdm import tqdm

MODES = ("auto", "bar", "log", "off")
DEFAULT_INTERVAL_S = 30.0


def _stream(stream: TextIO | None) -> TextIO:
    return sys.stderr if stream is None else stream


def resolve_mode(stream: TextIO | None = None, mode: str | None = None) -> str:
    """``bar``, ``log`` or ``off``: ``mode`` or ``$FORCDECODE_PROGRESS`` if given (``auto`` by
    default), ``auto`` meaning a bar on a terminal and lines otherwise."""
    mode = (mode or os.environ.get("FORCDECODE_PROGRESS") or "auto").strip().lower()
    if mode not in MODES:
        raise ValueError(f"progress mode must be one of {MODES}, not {mode!r}")
    if mode != "auto":
        return mode
    isatty = getattr(_stream(stream), "isatty", None)
    try:
        return "bar" if isatty is not None and isatty() else "log"
    except (ValueError, OSError):  # a closed or detached stream
        return "log"


def _interval(interval_s: float | None) -> float:
    if interval_s is not None:
        return float(interval_s)
    return float(os.environ.get("FORCDECODE_PROGRESS_INTERVAL_S", DEFAULT_INTERVAL_S))


def format_duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``2 h 07 min``."""
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


def _bar_size(stream: TextIO) -> dict:
    """tqdm's size options: follow the terminal, but a pty that reports no width or no height
    (some CI runners, ``script``) would get an invisible bar: 80 columns, 20 rows there."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, ValueError, OSError, io.UnsupportedOperation):
        size = os.terminal_size((0, 0))
    if size.columns > 0 and size.lines > 0:
        return dict(dynamic_ncols=True)
    return dict(ncols=size.columns if size.columns > 0 else 80, nrows=20)


def _timestamp() -> str:
    return datetime.now().strftime("%Y-%m-%d %H:%M:%S")


def _emit(line: str, stream: TextIO) -> None:
    """One line on ``stream``; running bars on the terminal are cleared first and redrawn after."""
    tqdm.write(line, file=stream)
    stream.flush()


def say(text: str, stream: TextIO | None = None) -> None:
    """Write ``text`` as one timestamped line on ``stream`` (default stderr), bar-safe."""
    _emit(f"[{_timestamp()}] {text}", _stream(stream))


def echo(text: str, stream: TextIO | None = None) -> None:
    """Write a result line as it is on ``stream`` (default stdout), bar-safe."""
    _emit(str(text), sys.stdout if stream is None else stream)


class Progress:
    """Progress of one piece of work (iterate over it, or call ``update``); see the module
    docstring. Made by :func:`progress`, which picks the mode."""

    def __init__(self, iterable: Iterable | None = None, *, total: int | None = None, desc: str = "",
                 unit: str = "it", stream: TextIO | None = None, mode: str = "log",
                 interval_s: float | None = None, clock: Callable[[], float] = time.monotonic):
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.iterable, self.total, self.desc, self.unit = iterable, total, desc, unit
        self.mode, self.stream, self.interval_s, self._clock = mode, _stream(stream), _interval(interval_s), clock
        self.n, self.status, self.closed = 0, "", False
        self._bar = None
        if mode == "bar":
            self._bar = tqdm(total=total, desc=desc, unit=f" {unit}", file=self.stream, leave=True,
                             **_bar_size(self.stream))
        self._start = self._last = clock()
        if mode == "log":
            self._line()

    # --- the tqdm-like interface ------------------------------------------------------------
    def __iter__(self):
        if self.iterable is None:
            raise TypeError("this Progress was made without an iterable: call update() instead")
        try:
            for item in self.iterable:
                yield item
                self.update()
        finally:
            self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def update(self, n: int = 1) -> None:
        """``n`` more units done."""
        self.update_to(self.n + n)

    def update_to(self, done: int, total: int | None = None) -> None:
        """``done`` units done (of ``total``, where it becomes known only now)."""
        if total is not None and total != self.total:
            self.total = total
            if self._bar is not None:
                self._bar.total = total
        step, self.n = done - self.n, done
        if self._bar is not None:
            self._bar.update(step)
        elif self.mode == "log" and self._clock() - self._last >= self.interval_s:
            if self.total is None or self.n < self.total:  # the end is written by close()
                self._line()

    def set_status(self, text: str) -> None:
        """A short status shown after the counts (the bar's postfix; the next log line's tail)."""
        self.status = str(text)
        if self._bar is not None:
            self._bar.set_postfix_str(self.status)

    def write(self, text: str) -> None:
        """A timestamped message line that does not break the bar (nothing when ``off``)."""
        if self.mode == "off":
            return
        _emit(f"[{_timestamp()}] {text}", self.stream)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self._bar is not None:
            self._bar.close()
        elif self.mode == "log":
            self._line(final=True)

    # --- log lines ------------------------------------------------------------------------
    def _line(self, final: bool = False) -> None:
        now = self._clock()
        self._last = now
        elapsed = now - self._start
        count = f"{self.n}/{self.total}" if self.total is not None else f"{self.n}"
        text = f"[{_timestamp()}] {self.desc + ': ' if self.desc else ''}{count} {self.unit}"
        if self.total:
            text += f" ({100.0 * self.n / self.total:.0f} %)"
        if self.n or final:
            text += f", elapsed {format_duration(elapsed)}"
        if final:
            text += ", done" if self.total is None or self.n >= self.total else ", stopped"
        elif self.n and self.total:
            text += f", about {format_duration(elapsed / self.n * (self.total - self.n))} left"
        if self.status:
            text += f" [{self.status}]"
        print(text, file=self.stream, flush=True)


def progress(iterable: Iterable | None = None, *, total: int | None = None, desc: str = "", unit: str = "it",
             stream: TextIO | None = None, mode: str | None = None, interval_s: float | None = None,
             clock: Callable[[], float] = time.monotonic) -> Progress:
    """Follow ``iterable`` (or ``total`` units counted with ``update``) on ``stream`` (default
    stderr): a bar on a terminal, lines every ``interval_s`` in a log (see :func:`resolve_mode`)."""
    stream = _stream(stream)
    return Progress(iterable, total=total, desc=desc, unit=unit, stream=stream,
                    mode=resolve_mode(stream, mode), interval_s=interval_s, clock=clock)


def counter(desc: str, unit: str = "it", **options) -> Callable[[int, int], None]:
    """A ``(done, total)`` callback for library functions that report that way (``resimulate``,
    ``quasistatic_family``): it opens a :func:`progress` at the first call and closes it when
    ``done == total``; a later call with ``done`` lower than before starts a new one."""
    state: dict = {"bar": None}

    def report(done: int, total: int) -> None:
        bar = state["bar"]
        if bar is None or bar.closed or done < bar.n:
            if bar is not None:
                bar.close()
            bar = state["bar"] = progress(total=total, desc=desc, unit=unit, **options)
        bar.update_to(done, total)
        if total is not None and done >= total:
            bar.close()

    return report
