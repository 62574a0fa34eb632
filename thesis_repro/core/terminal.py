"""Output that fits the terminal: its width, lines cut or wrapped to it, and a progress line with an ETA.

The command line prints what fits ``COLUMNS``, else the terminal's width; output that goes to a file or another
program without ``COLUMNS`` keeps its lines whole. ``--json`` or ``--verbose`` give the full text.

>>> cut("a" * 10, 6)
'aaaaa…'
>>> print(wrap("one two three four", 9))
one two
  three
  four
"""

from __future__ import annotations

import os
import shutil
import sys
import textwrap
import time
from typing import Any, TextIO

#: Width when neither a terminal nor ``COLUMNS`` says (output to a file or another program): lines stay whole.
UNLIMITED = 1_000_000
#: The narrowest width the kit formats for (a smaller ``COLUMNS`` is read as this).
MIN_COLUMNS = 40


def width() -> int:
    """The width to print within: ``COLUMNS`` if set, else the terminal's when standard output is one, else
    :data:`UNLIMITED`."""
    if os.environ.get("COLUMNS", "").strip().isdigit():
        return max(MIN_COLUMNS, int(os.environ["COLUMNS"]))
    if sys.stdout.isatty():
        return max(MIN_COLUMNS, shutil.get_terminal_size().columns)
    return UNLIMITED


def cut(line: str, cols: int | None = None) -> str:
    """``line`` cut to ``cols`` characters (default :func:`width`), an ellipsis marking the cut."""
    cols = width() if cols is None else cols
    return line if len(line) <= cols else line[: cols - 1] + "…"


def fit(text: str, cols: int | None = None) -> str:
    """Every line of ``text`` cut to ``cols`` (default :func:`width`).

    >>> fit("short\\n" + "x" * 50, 45).splitlines()[1]
    'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx…'
    """
    cols = width() if cols is None else cols
    return "\n".join(cut(line, cols) for line in text.splitlines())


def wrap(text: str, cols: int | None = None, indent: str = "  ") -> str:
    """Every line of ``text`` wrapped at ``cols`` (default :func:`width`), its continuation lines indented."""
    cols = width() if cols is None else cols
    out = []
    for line in text.splitlines() or [""]:
        lead = line[: len(line) - len(line.lstrip())]
        out += textwrap.wrap(line, cols, initial_indent="", subsequent_indent=lead + indent) or [""]
    return "\n".join(out)


def frame(df: Any, cols: int | None = None, **kwargs: Any) -> str:
    """A pandas frame as text within ``cols`` (default :func:`width`): pandas wraps its columns into blocks at
    that width, and a line still too long (a wide cell) is cut."""
    cols = width() if cols is None else cols
    return fit(df.to_string(line_width=cols, **kwargs), cols)


def duration(seconds: float) -> str:
    """``seconds`` as ``1h02``, ``3m05`` or ``42s``.

    >>> duration(42.4), duration(185), duration(3720)
    ('42s', '3m05', '1h02')
    """
    s = int(round(max(seconds, 0.0)))
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}"
    return f"{s}s"


class Progress:
    """A one-line progress report with an ETA on ``stream`` (default stderr), as wide as the terminal at most.

    On a terminal the line is rewritten in place (at most every ``every`` seconds); elsewhere (a file, a pipe)
    a line is written each time another tenth of the work is done. :meth:`close` ends the line.

    >>> import io; s = io.StringIO(); p = Progress("train", 100, stream=s)
    >>> p.update(50); p.close()
    >>> "train" in s.getvalue() and "50/100" in s.getvalue()
    True
    """

    def __init__(self, label: str, total: int, unit: str = "", stream: TextIO | None = None, every: float = 1.0):
        self.label, self.total, self.unit = label, max(int(total), 1), unit
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every, self.start, self.shown, self.tenth, self.done = every, time.monotonic(), 0.0, -1, 0

    def line(self) -> str:
        """The progress line: label, done/total, percent, elapsed time and the ETA."""
        elapsed = time.monotonic() - self.start
        frac = min(self.done / self.total, 1.0)
        if frac >= 1:
            eta = "done"
        else:  # extrapolated once a twentieth is done (the first steps carry the set-up)
            eta = f"ETA {duration(elapsed / frac * (1 - frac))}" if frac >= 0.05 else "ETA ?"
        unit = f" {self.unit}" if self.unit else ""
        return cut(f"{self.label}: {self.done:,}/{self.total:,}{unit} ({frac:.0%}), {duration(elapsed)}, {eta}")

    def update(self, done: int) -> None:
        """Report ``done`` units of work finished (rate-limited on a terminal, by tenths elsewhere)."""
        self.done = int(done)
        now = time.monotonic()
        if self.tty:
            if now - self.shown >= self.every or self.done >= self.total:
                self.stream.write("\r\x1b[K" + self.line())
                self.stream.flush()
                self.shown = now
            return
        tenth = min(10, 10 * self.done // self.total)
        if tenth > self.tenth:
            self.tenth = tenth
            self.stream.write(self.line() + "\n")
            self.stream.flush()

    def close(self) -> None:
        """End the progress line (on a terminal, a newline after the last state)."""
        if self.tty:
            self.stream.write("\r\x1b[K" + self.line() + "\n")
            self.stream.flush()
