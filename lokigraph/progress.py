"""Progress and logs of a run, on stderr.

* On a terminal: a tqdm bar with the frame, ms/frame and ETA, redrawn in place.
* Otherwise (a log file, a pipe, CI): plain lines, no ``\\r``: one per frame for short runs
  (at most ``short`` frames), else the first frame, one line every ``every`` seconds and the
  last frame.
* ``verbose``: one compact line per substep with the solver statistics of that substep (the dict
  :meth:`lokigraph.run.Simulation.step_substep` returns), printed above the bar on a terminal.

``lokigraph run --quiet`` creates none of this; the library's :func:`lokigraph.run.run` shows
progress only on a terminal unless asked.
"""

from __future__ import annotations

import io
import os
import shutil
import sys
import time
from collections import deque

import numpy as np


def _fmt_seconds(s: float) -> str:
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.1f} s"
    m, s = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def _fmt_value(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        return str(int(v)) if v.is_integer() and abs(v) < 1e15 else f"{v:.4g}"
    return str(v)


def substep_line(frame: int, substep: int, substeps: int, time_s: float, seconds: float,
                 stats: dict) -> str:
    """``frame 3 substep 2/4 t=0.1042 1.3 ms contacts_vf=12 ...`` (keys sorted)."""
    parts = [f"frame {frame} substep {substep}/{substeps} t={time_s:.4f} {seconds * 1e3:.1f} ms"]
    parts += [f"{k}={_fmt_value(stats[k])}" for k in sorted(stats)]
    return " ".join(parts)


class RunProgress:
    """Progress of a run simulating frames ``start+1 .. last`` (``total`` frames).

    ``update(frame, seconds)`` after each simulated frame; ``substep(...)`` per substep when
    ``verbose``; ``close()`` at the end (also on failure). ``show`` false keeps only the
    verbose lines. ``tty`` (default: ``stream.isatty()``) picks the bar or plain lines.
    """

    def __init__(self, start: int, last: int, stream=None, *, show: bool = True,
                 verbose: bool = False, tty: bool | None = None, every: float = 5.0,
                 short: int = 30, window: int = 10):
        self.stream = stream if stream is not None else sys.stderr
        self.start, self.last = start, last
        self.total = max(last - start, 0)
        self.show, self.verbose = show, verbose
        if tty is None:
            try:
                tty = bool(self.stream.isatty())
            except (AttributeError, ValueError):
                tty = False
        self.tty = tty
        self.every, self.short = every, short
        self.recent: deque = deque(maxlen=window)
        self.done = 0
        self.t0 = time.perf_counter()
        self.t_line = None  # time of the last plain line
        self.bar = None  # the tqdm bar, created at the first frame (nothing drawn before)
        self.drawn = False  # the fallback bar (no tqdm) drew something

    def _make_bar(self, frame: int, ms: float):
        try:
            from tqdm import tqdm
        except ImportError:  # pragma: no cover - tqdm is a core dependency
            return None
        cols, rows = self._size()
        return tqdm(total=self.total, file=self.stream, ncols=cols, nrows=rows, leave=True,
                    smoothing=0.3, mininterval=0.1, desc=f"frame {frame}",
                    postfix=f"{ms:.1f} ms/frame",
                    bar_format="{desc} {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} "
                               "[{elapsed}<{remaining} ETA{postfix}]")

    def _size(self) -> tuple[int, int]:
        """The terminal's columns and lines (a pseudo-terminal may report 0 x 0, which tqdm
        would take as "no room": then $COLUMNS/$LINES or 80 x 24)."""
        try:
            cols, rows = os.get_terminal_size(self.stream.fileno())
        except (AttributeError, ValueError, OSError, io.UnsupportedOperation):
            cols = rows = 0
        fallback = shutil.get_terminal_size((80, 24))
        return cols if cols > 0 else fallback.columns, rows if rows > 0 else fallback.lines

    # -- per frame --
    def ms_per_frame(self) -> float:
        return 1e3 * sum(self.recent) / max(len(self.recent), 1)

    def eta(self) -> float:
        return (self.total - self.done) * self.ms_per_frame() / 1e3

    def update(self, frame: int, seconds: float) -> None:
        self.done += 1
        self.recent.append(float(seconds))
        if not self.show or not self.total:
            return
        ms = self.ms_per_frame()
        if self.tty and self.bar is None and not self.drawn:
            self.bar = self._make_bar(frame, ms)
        if self.bar is not None:
            self.bar.set_description_str(f"frame {frame}", refresh=False)
            self.bar.set_postfix_str(f"{ms:.1f} ms/frame", refresh=False)
            self.bar.update(1)
        elif self.tty:  # no tqdm: a plain \r bar
            frac = self.done / self.total
            width = 30
            fill = "#" * int(width * frac) + "-" * (width - int(width * frac))
            self._write(f"\rframe {frame} [{fill}] {self.done}/{self.total} {ms:.1f} ms/frame "
                        f"ETA {_fmt_seconds(self.eta())}  ", newline=False)
            self.drawn = True
        else:
            now = time.perf_counter()
            if (self.total <= self.short or self.t_line is None or self.done == self.total
                    or now - self.t_line >= self.every):
                self.t_line = now
                self._write(self._line(frame))

    def _line(self, frame: int) -> str:
        pct = 100.0 * self.done / self.total
        return (f"frame {frame} ({self.done}/{self.total}, {pct:.0f}%) "
                f"{self.ms_per_frame():.1f} ms/frame, elapsed "
                f"{_fmt_seconds(time.perf_counter() - self.t0)}, ETA {_fmt_seconds(self.eta())}")

    # -- per substep (verbose) --
    def substep(self, frame: int, substep: int, substeps: int, time_s: float, seconds: float,
                stats: dict) -> None:
        if self.verbose:
            self.write(substep_line(frame, substep, substeps, time_s, seconds, stats))

    def write(self, line: str) -> None:
        """A line on the stream, above the bar when one is shown."""
        if self.bar is not None:
            self.bar.write(line, file=self.stream)
        else:
            if self.drawn:
                self._write("\r", newline=False)
            self._write(line)

    def _write(self, text: str, newline: bool = True) -> None:
        self.stream.write(text + ("\n" if newline else ""))
        self.stream.flush()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        elif self.drawn:
            self._write("")
            self.drawn = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
