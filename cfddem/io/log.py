"""Run log (``OUT/run.log``), the rate limit on repeated warnings, and a one-line progress
display."""

from __future__ import annotations

import logging
import math
import sys
import time as _time
from pathlib import Path
from typing import Callable, TextIO

_FMT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"


def setup_run_logger(out_dir, stderr: bool = False, level: int = logging.INFO,
                     name: str = "cfddem") -> logging.Logger:
    """Return the ``cfddem`` logger writing to ``out_dir/run.log`` (appending; a restarted
    run continues the same log) and, with ``stderr=True``, INFO and above to stderr.

    Handlers installed by an earlier call are replaced, so calling it once per run in the
    same process (tests, sweeps) does not duplicate lines. Modules log through child
    loggers (``logging.getLogger("cfddem.gas")``), which propagate here. Repeated warnings
    are rate-limited (:class:`RepeatLimit`); :func:`log_repeat_totals` logs their totals.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    logger = logging.getLogger(name)
    for h in list(logger.handlers):
        if getattr(h, "_cfddem_run", False):
            logger.removeHandler(h)
            h.close()
    logger.setLevel(level)
    logger.propagate = False
    repeats = RepeatLimit()  # one per run: the end-of-run counts are this run's
    fh = logging.FileHandler(out / "run.log", mode="a", encoding="utf-8")
    fh.setFormatter(logging.Formatter(_FMT))
    fh.setLevel(level)
    handlers = [fh]
    if stderr:
        sh = logging.StreamHandler(sys.stderr)
        sh.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
        sh.setLevel(logging.INFO)
        handlers.append(sh)
    for h in handlers:
        h.addFilter(repeats)
        h._cfddem_run = True
        logger.addHandler(h)
    return logger


class RepeatLimit(logging.Filter):
    """Rate limit on repeated warnings: a warning (or error) whose message template
    (``record.msg``, the text before ``%`` formatting, with the logger's name) comes again is
    logged at its 1st, 10th, 100th, 1000th, ... occurrence only, the repeats marked
    ``[10th time; repeats are counted, the total is logged at the end of the run]``; the others
    are counted. :meth:`summary_lines` (logged at the end of a run by :func:`log_repeat_totals`)
    gives, per template seen more than once, its total and the last formatted message.

    The logged lines thus grow with the logarithm of the count (a run of a million repeats
    logs 7 lines and its total): the first occurrence shows what happened and when, the
    decades show whether it keeps happening, the total says how often. Records below WARNING
    pass untouched (periodic INFO lines, checkpoints and progress, are meant to repeat).

    Installed on each handler of the run logger (the filters of a logger do not see records
    of its child loggers); a record that reaches several handlers is counted once.
    """

    def __init__(self, level: int = logging.WARNING):
        super().__init__()
        self.level = level
        self.counts: dict[tuple[str, str], int] = {}
        self.last: dict[tuple[str, str], str] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        seen = getattr(record, "_cfddem_repeat", None)
        if seen is not None:  # the same record at a second handler
            return seen
        if record.levelno < self.level:
            return True
        key = (record.name, str(record.msg))
        n = self.counts.get(key, 0) + 1
        self.counts[key] = n
        self.last[key] = record.getMessage()
        show = _is_decade(n)
        if show and n > 1:
            record.msg = f"{self.last[key]} [{n}th time; repeats are counted, the total is logged at " \
                         "the end of the run]"  # n is 10, 100, ...: always "th"
            record.args = None
        record._cfddem_repeat = show
        return show

    def summary_lines(self) -> list[str]:
        """One line per message template logged more than once: total, lines shown, the last."""
        lines = []
        for key, n in self.counts.items():
            if n > 1:
                shown = len(str(n))  # the decades up to n
                lines.append(f"warning repeated {n} times in this run ({shown} logged), the last: {self.last[key]}")
        return lines


def _is_decade(n: int) -> bool:
    """1, 10, 100, 1000, ...: the occurrences of a repeated warning that are logged."""
    while n % 10 == 0:
        n //= 10
    return n == 1


def log_repeat_totals(logger: logging.Logger) -> list[str]:
    """Log (INFO) the totals of the warnings that :class:`RepeatLimit` rate-limited on this
    run logger's handlers (nothing for a logger that :func:`setup_run_logger` did not set
    up); returns the lines."""
    limits = {id(f): f for h in logger.handlers for f in h.filters if isinstance(f, RepeatLimit)}
    lines = [line for f in limits.values() for line in f.summary_lines()]
    for line in lines:
        logger.info(line)
    return lines


def _fmt_duration(s: float) -> str:
    if not math.isfinite(s) or s < 0:
        return "--:--"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h:d}:{m:02d}:{sec:02d}" if h else f"{m:02d}:{sec:02d}"


class Progress:
    """One-line progress: ``t = 1.2345 / 6 s | 26012 particles | 812 steps/s | ETA 12:03``.

    On a TTY the line is redrawn in place (carriage return) at most every ``interval``
    seconds; otherwise (a log file, a batch job) a plain line is printed every
    ``line_interval`` seconds. The rates are measured between two displayed updates:
    steps/s = steps done / wall time, ETA = (end_time - time) / (simulated time per wall
    second). ``clock`` and ``is_tty`` can be injected for tests.
    """

    def __init__(self, end_time: float, stream: TextIO | None = None, interval: float = 1.0,
                 line_interval: float = 30.0, is_tty: bool | None = None,
                 clock: Callable[[], float] = _time.monotonic):
        self.end_time = float(end_time)
        self.stream = stream if stream is not None else sys.stderr
        self.is_tty = bool(getattr(self.stream, "isatty", lambda: False)()) if is_tty is None else is_tty
        self.interval = interval if self.is_tty else line_interval
        self.clock = clock
        self._last_wall: float | None = None
        self._last_time = 0.0
        self._last_step = 0
        self._width = 0
        self.lines_written = 0
        self.last_line = ""

    def update(self, time: float, n_particles: int, step: int, force: bool = False) -> bool:
        """Show the state if at least ``interval`` seconds passed since the last display
        (the first call only starts the clocks). Returns True when something was shown."""
        now = self.clock()
        if self._last_wall is None:
            self._last_wall, self._last_time, self._last_step = now, float(time), int(step)
            return False
        dt_wall = now - self._last_wall
        if dt_wall < self.interval and not force:
            return False
        if dt_wall <= 0.0:
            return False
        steps_s = (step - self._last_step) / dt_wall
        sim_rate = (time - self._last_time) / dt_wall
        eta = (self.end_time - time) / sim_rate if sim_rate > 0 else math.inf
        line = (f"t = {time:.4f} / {self.end_time:g} s | {int(n_particles)} particles | "
                f"{steps_s:.0f} steps/s | ETA {_fmt_duration(eta)}")
        if self.is_tty:
            pad = " " * max(0, self._width - len(line))
            self.stream.write("\r" + line + pad)
            self._width = len(line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self.last_line = line
        self.lines_written += 1
        self._last_wall, self._last_time, self._last_step = now, float(time), int(step)
        return True

    def close(self) -> None:
        """End the progress line (newline on a TTY)."""
        if self.is_tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0
