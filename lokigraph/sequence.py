"""Mesh sequences of kinematic elements: ``geometry: {sequence: "anim/body.{frame:04d}.obj"}``.

The pattern holds ``{frame}`` or ``{frame:0Nd}`` fields and nothing else in braces. ``hold``
says what a frame without a file shows:

* ``error`` (default): every frame the run needs (the scene's ``frames.start`` .. ``end``) must
  have a file; a missing one is an input error naming the frame and the file;
* ``first``: frames before the sequence's first file and after its last show its first file;
* ``last``: frames before the first file show the first, frames after the last file show the
  last (the pose is held);
* ``loop``: the sequence repeats: frame f shows file first + (f - first) mod (last - first + 1).

A gap inside the sequence (a missing file between two present ones) holds the file before it
in every mode but ``error``. Positions are interpolated linearly between consecutive frames.

A USD prim (``geometry: {usd: body.usd, prim: /char/body}``) is a sequence too: the scene puts a
:class:`UsdSource` where the pattern stands (``GeometrySpec.sequence``), and the functions here
give its frames (the time samples of its points, see :mod:`lokigraph.usd`).
"""

from __future__ import annotations

import os
import re
import string
from pathlib import Path

import numpy as np

HOLD_MODES = ("error", "first", "last", "loop")


class UsdSource(str):
    """The frames of a USD mesh prim, standing where a sequence pattern stands: the string is
    the USD file (relative to the scene file); ``prim`` is the prim path and ``fps`` the scene's
    frame rate (time code of frame f: f * the stage's timeCodesPerSecond / fps)."""

    def __new__(cls, usd: str, prim: str, fps: float | None = None):
        s = super().__new__(cls, usd)
        s.prim = prim
        s.fps = fps
        return s

    def __reduce__(self):
        return (UsdSource, (str(self), self.prim, self.fps))

    def __repr__(self):
        return f"UsdSource({str(self)!r}, prim={self.prim!r}, fps={self.fps!r})"


def frame_file(pattern: str, frame: int) -> str:
    """The file name of ``frame`` (pattern checked by lokigraph.scene.check_sequence_pattern;
    a :class:`UsdSource` gives its USD file for every frame)."""
    if isinstance(pattern, UsdSource):
        return str(pattern)
    return pattern.format(frame=int(frame))


def available_frames(pattern: str, base: Path) -> np.ndarray | None:
    """Sorted frame numbers that have a file, from one directory listing; None when the
    directory part of the pattern holds ``{frame}`` or cannot be listed.

    For a :class:`UsdSource`: the frames with a time sample of the prim's points; None when the
    points are not time-sampled (a static prim) or the file cannot be read."""
    if isinstance(pattern, UsdSource):
        from .geometry import MeshReadError
        from .usd import usd_frames

        try:
            return usd_frames(Path(base) / str(pattern), pattern.prim, pattern.fps)
        except MeshReadError:
            return None
    head, _, tail = pattern.replace("\\", "/").rpartition("/")
    if "{" in head:
        return None
    folder = Path(base) / head if head else Path(base)
    rx = []
    for literal, name, _spec, _conv in string.Formatter().parse(tail):
        rx.append(re.escape(literal))
        if name is not None:
            rx.append(r"(-?\d+)")
    regex = re.compile("^" + "".join(rx) + "$")
    found = []
    try:
        with os.scandir(folder) as it:
            for ent in it:
                m = regex.match(ent.name)
                if m is None:
                    continue
                nums = {int(g) for g in m.groups()}
                if len(nums) != 1:
                    continue
                f = nums.pop()
                if tail.format(frame=f) == ent.name:
                    found.append(f)
    except OSError:
        return None
    return np.unique(np.asarray(found, dtype=np.int64))


def first_missing(available: np.ndarray, start: int, end: int) -> int | None:
    """The first frame in [start, end] without a file, or None when all are present."""
    a = available[(available >= start) & (available <= end)]
    if len(a) == end - start + 1:
        return None
    expect = np.arange(start, start + len(a) + 1)
    k = int(np.argmax(np.append(a, end + 1) != expect))
    return int(expect[k])


def describe_frames(available: np.ndarray) -> str:
    if available is None or not len(available):
        return "no files"
    if len(available) == int(available[-1] - available[0]) + 1:
        return f"frames {int(available[0])}..{int(available[-1])}"
    return (f"{len(available)} files between frames {int(available[0])} and "
            f"{int(available[-1])} (with gaps)")


def map_frame(frame: int, available: np.ndarray, hold: str) -> int | None:
    """The frame whose file shows ``frame`` under ``hold``; None if there is none."""
    if available is None or not len(available):
        return None
    lo, hi = int(available[0]), int(available[-1])
    f = int(frame)
    if hold == "error":
        i = int(np.searchsorted(available, f))
        return f if i < len(available) and available[i] == f else None
    if f < lo or f > hi:
        if hold == "loop":
            f = lo + (f - lo) % (hi - lo + 1)
        elif hold == "first" or f < lo:
            return lo
        else:
            return hi
    i = int(np.searchsorted(available, f, side="right")) - 1  # gap: the file before it
    return int(available[max(i, 0)])
